"""``nhstab plan``: a feasible, collision-free, stabilizable nominal trajectory on a map."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click
from nhstab.limits import DEFAULT_HEADROOM

from .map import load, map_options, parse_pose, pose_keys
from .options import cli_robot, effective_doc, effective_yaml, out_option, robot_options

#: exit code when the request is valid but no plan was found within the budget
EXIT_NO_PLAN = 3
#: exit code when the plan is written but its tube could not be predicted
EXIT_FAILURE = 1
#: the control rate [Hz] the plan's error tube is predicted at (nhstab run's default)
TUBE_RATE_HZ = 50.0
#: exit code when interrupted (a Ctrl-C while the plan's files are written: they are completed first)
EXIT_INTERRUPTED = 130


@click.command()
@click.argument("map_file", metavar="MAP", type=click.Path(path_type=Path))
@robot_options
@click.option("--start", default=None, help="Start: the pose x,y,theta (a car_trailer may add its trailer angle theta1), or the robot's full state in its state order with phi = 0, e.g. rwd_car x,y,theta,0 (default: the map's).")
@click.option("--goal", default=None, help="Goal: the pose x,y,theta (a car_trailer may add its trailer angle theta1), or the robot's full state in its state order with phi = 0, e.g. rwd_car x,y,theta,0 (default: the map's).")
@click.option("--problem", type=int, default=None, help="Use the map's start/goal problem with this index.")
@click.option("--planner", default="rrtconnect", show_default=True, help="OMPL planner: rrtconnect, rrtstar, bitstar, prmstar, ...")
@click.option("--space", default=None,
              help="reeds_shepp (forward and reverse) or dubins (forward only) (default: the robot's space, e.g. "
                   "dubins for a Nav2 DUBIN robot, else reeds_shepp).")
@click.option("--turning-radius", type=float, default=None,
              help="[m] (default: the robot's: unicycle 0.5, cars 1.25 x their minimum).")
@click.option("--time-limit", type=float, default=2.0, show_default=True, help="Planning budget [s].")
@click.option("--seed", type=int, default=0, show_default=True, help="OMPL's random seed for this call.")
@click.option("--guide/--no-guide", default=True, show_default=True,
              help="Guided search: a grid shortest path sets subgoals; --no-guide: OMPL over the whole map.")
@click.option("--margin", default=None,
              help="Clearance to keep from known obstacles [m] (default: the robot's margin), or auto: the smallest "
                   "margin whose error tube is certified clear (a few rounds of planning).")
@click.option("--gains", default="default", show_default=True,
              help="default (the robot's alpha, delta, gamma) or auto (per plan, the narrowest tube with a saturation "
                   "probability under 1 %).")
@click.option("--fit", is_flag=True,
              help="When the plan's error tube is not certified clear, try the margin it needs (where the room "
                   "allows) and other maneuvers, and keep the best (plan.json's fit lists every try).")
@click.option("--noise", "noise_scale", type=float, default=1.0, show_default=True,
              help="Noise level the tube is predicted for (a multiple of nhstab run's default noise).")
@click.option("--process-per", type=click.Choice(["second", "metre"]), default="second", show_default=True,
              help="The tube's process disturbance acts per second (at rest too) or per metre travelled (none at "
                   "rest), as nhstab run --process-per.")
@click.option("--probability", type=float, default=0.997, show_default=True, help="Probability of the error tube.")
@click.option("--tube", "tube_kind", type=click.Choice(["auto", "linear", "sampled"]), default="auto", show_default=True,
              help="The error tube: linear (the closed loop linearised along the nominal, per sample), sampled "
                   "(rollouts of the run loop, a certificate for the whole run), or auto: linear where inputs do "
                   "not saturate and the plan has no stop, sampled elsewhere.")
@click.option("--confidence", type=float, default=0.95, show_default=True,
              help="Confidence of the sampled tube's certificate: N >= ln(1 - confidence) / ln(p) rollouts.")
@click.option("--headroom", type=float, default=None,
              help="Plan within this fraction of the input limits, leaving the rest to the feedback (default: "
                   f"nhstab run's, {DEFAULT_HEADROOM:g}; the tube's saturation probability is against the full limits).")
@click.option("--max-speed", type=float, default=None, help="[m/s] (default: the robot's limit).")
@out_option("plan", "trajectory.csv, trajectory.npz, tube.npz, plan.json and plan.png")
@click.option("--figure/--no-figure", default=True, show_default=True,
              help="Draw plan.png (--no-figure: skip it and matplotlib's drawing stack, for scripted planning).")
@click.option("--print-config", is_flag=True,
              help="Print the effective plan configuration (YAML: the map, robot, start, goal and every option, its "
                   "defaults filled in, in a run config's sections) and exit without planning.")
@map_options
def plan(map_file, robot, robot_config, start, goal, problem, planner, space, turning_radius, time_limit, seed, guide,
         margin, gains, fit, noise_scale, process_per, probability, tube_kind, confidence, headroom, max_speed, out_dir,
         figure,
         print_config, cell_size, unknown):
    """Plan on MAP and write trajectory.csv, trajectory.npz, plan.json and plan.png into OUT (default out/plan).

    The robot (model, footprint, margin, turning radius, space, stabilizer) comes from --robot-config,
    else --robot, else the map's robot block, else the unicycle. The plan's error tube (nhstab run's
    default noise times --noise, 50 Hz, the gramian law) is drawn in plan.png, summarised in
    plan.json (``tube``) and stored in tube.npz.

    Exit code 2 for a bad request (start or goal out of bounds or in collision, unknown planner, zero
    budget, ...), 3 when no plan was found within the budget (nothing is written then), 1 when the plan is
    found but its tube cannot be predicted (the linearised loop diverges under the law: the plan is
    written, plan.json's ``tube_error`` says why), 130 when interrupted (a Ctrl-C once the plan is found
    does not stop its files being written).
    """
    from nhstab.errors import InputError
    from nhstab.execution import write_plan
    from nhstab.execution.config import NoiseOptions
    from nhstab.execution.runner import derated
    from nhstab.limits import MAX_NOISE_SCALE, check_probability, check_range
    from nhstab.maps import resolve_poses
    from nhstab.planning import PathOptions, TimingOptions
    from nhstab.tubes.base import saturation_text, tube_line
    from nhstab.tubes.fit import plan_and_tube

    margin = None if margin is None else parse_margin("--margin", margin)
    check_probability("--probability", probability)
    if not (0.0 < confidence < 1.0):
        raise InputError("--confidence", "a number in (0, 1)", confidence)
    from nhstab.tubes.base import rollouts_needed

    try:
        rollouts_needed(probability, confidence)
    except InputError as exc:
        raise InputError("--confidence", exc.expected, confidence, detail=exc.detail) from None
    check_range("--noise", noise_scale, 0.0, MAX_NOISE_SCALE)
    if headroom is None:
        headroom = DEFAULT_HEADROOM
    if not (0.0 < headroom <= 1.0):
        raise InputError("--headroom", "a number in (0, 1]", headroom)

    from nhstab.errors import InputError, user_keys
    from nhstab.limits import MAX_PLANNER_SEED, check_int
    from nhstab.planning import check_plannable

    check_int("--seed", seed, 0, MAX_PLANNER_SEED, "an integer (OMPL's seed)")
    m = load(map_file, cell_size, unknown)
    rob = cli_robot(robot, robot_config, None, m.robot, m)
    check_plannable(rob, "--robot" if robot else ("--robot-config" if robot_config else f"robot.model (in {map_file})"))
    s, g = resolve_poses(m, parse_pose("--start", start), parse_pose("--goal", goal), problem,
                         names=("--start", "--goal", "--problem"))
    # the options name the errors about their values (the robot's keys name the robot's): the nominal's
    # speed is --max-speed's, else the robot's limit scaled by --headroom
    names = {**pose_keys(m, start, goal, problem), "space": "--space" if space is not None else rob.key("space"), "planner": "--planner", "time_limit_s": "--time-limit", "seed": "--seed",
             "margin": "--margin" if margin is not None else rob.key("margin"),
             "turning_radius": "--turning-radius" if turning_radius is not None else rob.key("turning_radius"),
             "max_speed": "--max-speed" if max_speed is not None
             else ("--headroom", headroom) if headroom not in (DEFAULT_HEADROOM, 1.0)
             else (rob.key("max_speed"), getattr(rob.model, "max_speed", None))}
    from nhstab.control import StabilizerOptions

    with user_keys(rob.stabilizer_keys()):        # the gain schedule's window against the nominal's time step
        StabilizerOptions(**rob.stabilizer.as_dict()).validated().check_step(TimingOptions().dt)
    with user_keys(names):
        pose_names = ("--start" if start is not None and problem is None else "start",
                      "--goal" if goal is not None and problem is None else "goal")
        s, g = rob.configuration(s, pose_names[0]), rob.configuration(g, pose_names[1])
        path_opts = PathOptions(space=space, turning_radius=turning_radius, planner=planner, time_limit_s=time_limit,
                                seed=seed, margin=None if margin in (None, "auto") else margin, guide=guide)
        if margin is None:
            margin = rob.margin
        plan_robot = rob.with_model(derated(rob.model, headroom)) if headroom < 1.0 else rob
        path_opts = path_opts.for_robot(plan_robot)
        tube_noise = NoiseOptions(scale=noise_scale, process_per=process_per)
        if print_config:
            click.echo(effective_plan_config(
                m, str(map_file), rob, plan_robot, s, g, path_opts, margin=margin, gains=gains, fit=fit,
                timing=TimingOptions(max_speed=max_speed), noise=tube_noise, headroom=headroom,
                tube={"kind": tube_kind, "probability": probability, "confidence": confidence}, figure=figure,
                rate_hz=TUBE_RATE_HZ, pose_names=pose_names), nl=False)
            return 0
        result, law, tube, extra = plan_and_tube(m, rob, s, g, path_opts, TimingOptions(max_speed=max_speed),
                                                 margin=margin, gains=gains, noise=tube_noise,
                                                 probability=probability, plan_robot=plan_robot, tube_kind=tube_kind,
                                                 confidence=confidence, fit=fit, rate_hz=TUBE_RATE_HZ)
    for key in ("margin_auto", "gains_auto", "fit"):
        if key in extra:
            click.echo(extra[key]["message"])
    if law is None:
        click.echo(f"nhstab: no plan ({result.status}): {result.message}", err=True)
        if "likely_cause" in result.metrics:
            click.echo(result.metrics["likely_cause"]["text"], err=True)
        return EXIT_NO_PLAN
    if margin == "auto":
        path_opts = replace(path_opts, margin=extra["margin_auto"]["margin_m"])
    elif "fit_margin_m" in extra:
        path_opts = replace(path_opts, margin=extra["fit_margin_m"])
    if "fit" in extra:
        row = extra["fit"]["tries"][extra["fit"]["chosen"]]
        path_opts = replace(path_opts, seed=(path_opts.seed + row["seed_offset"]) % (2**31 - 1))
    from nhstab.interrupts import holding_interrupts, interrupt_held

    with holding_interrupts():      # from here a Ctrl-C does not lose the plan: its files are completed, then exit 130
        write_plan(result, out_dir, m, str(map_file), rob, s, g, path_opts, figures=figure, tube=tube,
                   extra={**extra, "headroom": headroom})
    if interrupt_held():
        click.echo(f"nhstab: interrupted after planning; the plan's files in {out_dir} are complete", err=True)
        return EXIT_INTERRUPTED
    met = result.metrics
    cusps = met["cusps"]
    click.echo(f"plan found for {rob.name}: {met['length_m']:.2f} m, {cusps} cusp{'' if cusps == 1 else 's'}, "
               f"{met['duration_s']:.1f} s, min clearance {met['min_clearance_m']:.3f} m (margin {path_opts.margin:.3g} m), "
               f"max gain {met['max_gain_norm']:.3g}")
    if tube is None:                # the plan is written; its tube could not be predicted (plan.json says why)
        click.echo(f"wrote {out_dir}/trajectory.csv, trajectory.npz, plan.json" + (", plan.png" if figure else ""))
        click.echo(f"nhstab: no tube: {extra.get('tube_error', 'not predicted')}", err=True)
        return EXIT_FAILURE
    click.echo(tube_line(tube, noise_scale, noise=tube_noise))
    if headroom > DEFAULT_HEADROOM and tube.kind != "sampled" and tube.saturation["run_bound"] > 0.01:
        click.echo(f"note: planned with --headroom {headroom:g}, the nominal leaves the feedback little of the input "
                   f"limits: {saturation_text(tube.saturation['run_bound'])}; --headroom {DEFAULT_HEADROOM:g} (the "
                   f"default) leaves it {100 * (1 - DEFAULT_HEADROOM):.0f} %")
    elif headroom > DEFAULT_HEADROOM and tube.kind == "sampled" and tube.saturation["observed_fraction"] > 0.01:
        click.echo(f"note: planned with --headroom {headroom:g}, inputs reach a limit in "
                   f"{100 * tube.saturation['observed_fraction']:.0f} % of rollouts; --headroom {DEFAULT_HEADROOM:g} "
                   f"(the default) leaves the feedback {100 * (1 - DEFAULT_HEADROOM):.0f} % of the limits")
    click.echo(f"wrote {out_dir}/trajectory.csv, trajectory.npz, tube.npz, plan.json" + (", plan.png" if figure else ""))
    return 0


def effective_plan_config(m, map_path: str, robot, plan_robot, start, goal, path_opts, *, margin, gains: str,
                          fit: bool, timing, noise, headroom: float, tube: dict, figure: bool, rate_hz: float,
                          pose_names: tuple[str, str] = ("start", "goal")) -> str:
    """What ``nhstab plan`` would plan with (YAML): the map, the robot's full description, start and goal,
    then its options in a run config's sections with every default filled in (``path_opts`` already
    given the robot's space, turning radius and margin): ``planning`` (the search; ``seed`` is OMPL's),
    ``controller`` (the gain setting and the robot's alpha, delta, gamma the tube's gramian law uses),
    ``headroom`` and ``max_speed`` (the nominal's top speed [m/s]), ``noise`` (the tube's, every state's
    level), ``tube`` and ``rate_hz`` (the tube's control rate). Checked as the plan checks them before it
    searches (the start and goal: inside the bounds, clear of the known obstacles by the margin)."""
    import numpy as np
    from nhstab.collision import CollisionWorld, check_poses
    from nhstab.errors import InputError
    from nhstab.execution.config import DEFAULT_NOISE
    from nhstab.planning import check_map_budget
    from nhstab.planning.trailer import check_configuration
    from nhstab.tubes.fit import SEVERAL_BODIES

    doc = effective_doc(m, map_path, robot, start, goal, pose_names=pose_names)
    path_opts = path_opts.validated()
    check_map_budget(m, path_opts.time_limit_s, path_opts.resolution)
    if path_opts.turning_radius < plan_robot.min_turning_radius - 1e-9:
        raise InputError("turning_radius", f"at least the {robot.model.name}'s minimum turning radius "
                         f"{plan_robot.min_turning_radius:.4g} m", path_opts.turning_radius)
    if robot.trailers and path_opts.space != "reeds_shepp":
        raise InputError("space", "reeds_shepp (a car with a trailer reverses)", path_opts.space)
    if gains not in ("default", "auto"):
        raise InputError("--gains", "default or auto", gains)
    if len(robot.footprints) > 1 and margin == "auto":
        raise InputError("--margin", SEVERAL_BODIES, margin)
    timing = timing.validated()
    noise.validated(robot.state_names)
    # the start and goal as the search takes them: inside the bounds, clear of the known obstacles, by the margin
    world = CollisionWorld.from_map(m, "known")
    for key in ("start", "goal"):
        config = np.asarray(doc[key], dtype=float)
        c = (check_configuration(m, robot, config, key, world) if robot.trailers else
             check_poses(m, robot.footprint, {key: config[:3]}, world=world)[key])
        if margin != "auto" and c <= path_opts.margin:
            raise InputError(key, f"a pose at least the margin {path_opts.margin:.3g} m from the known obstacles",
                             np.round(config, 4).tolist(), detail=f"clearance {c:.3g} m")
    max_speed = timing.max_speed if timing.max_speed is not None else getattr(plan_robot.model, "max_speed", None)
    levels = {k: {s: float(getattr(noise, k).get(s, DEFAULT_NOISE[k].get(s, 0.0))) for s in robot.state_names}
              for k in ("initial", "sensor", "process")}
    doc.update({
        "headroom": float(headroom),
        **({"max_speed": float(max_speed)} if max_speed is not None else {}),
        "rate_hz": float(rate_hz),
        "controller": {"kind": "gramian", "window": "future", "gains": gains,
                       **{k: float(v) for k, v in robot.stabilizer.as_dict().items() if k in ("alpha", "delta", "gamma")}},
        "noise": {"scale": float(noise.scale), "initial": {"distribution": noise.distribution, **levels["initial"]},
                  "sensor": levels["sensor"], "process": {"per": noise.process_per, **levels["process"]}},
        "planning": {"planner": path_opts.planner, "space": path_opts.space,
                     "time_limit_s": float(path_opts.time_limit_s), "seed": int(path_opts.seed),
                     "margin": margin if margin == "auto" else float(path_opts.margin),
                     "turning_radius": float(path_opts.turning_radius), "guide": bool(path_opts.guide),
                     "fit": bool(fit)},
        "tube": {"kind": tube["kind"], "probability": float(tube["probability"]),
                 "confidence": float(tube["confidence"])},
        "figure": bool(figure),
    })
    return effective_yaml("the effective plan configuration of nhstab plan: every option with its default filled in "
                          "(sections as in a run config)", doc)


def parse_margin(name: str, text):
    """A margin option: a number >= 0 [m] or ``auto``; None stays None."""
    from nhstab.errors import InputError

    if text is None or text == "auto":
        return text
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise InputError(name, "a number >= 0 [m] or auto", text) from None
    from nhstab.limits import MAX_COORD_M

    if not (0.0 <= value <= MAX_COORD_M):
        raise InputError(name, f"a number in [0, {MAX_COORD_M:g}] m or auto", text)
    return value


@click.command()
@click.option("--map", "map_file", default="example:parking_lot",
              show_default=True)
@click.option("--seed", type=int, default=1, show_default=True)
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("results/planning"),
              show_default=True)
def sweep(map_file, seed, out_dir):
    """The stabilizer-parameter sweep behind the per-robot defaults: writes sweep.json and sweep.md."""
    from nhstab.planning.sweep import sweep as run_sweep
    from nhstab.planning.sweep import sweep_markdown
    from nhstab.records import write_json, write_text

    result = run_sweep(map_file, seed)
    write_json(out_dir / "sweep.json", result)
    write_text(out_dir / "sweep.md", sweep_markdown(result))
    click.echo(sweep_markdown(result))
    click.echo(f"chosen: {result['chosen']}")
    return 0
