"""``nhstab plan``: a feasible, collision-free, stabilizable nominal trajectory on a map."""

from __future__ import annotations

from pathlib import Path

import click

from .map import load, map_options, parse_pose
from .options import cli_robot, robot_options

#: exit code when the request is valid but no plan was found within the budget
EXIT_NO_PLAN = 3


@click.command()
@click.argument("map_file", metavar="MAP", type=click.Path(path_type=Path))
@robot_options
@click.option("--start", default=None, help="Start pose x,y,theta (default: the map's).")
@click.option("--goal", default=None, help="Goal pose x,y,theta (default: the map's).")
@click.option("--problem", type=int, default=None, help="Use the map's start/goal problem with this index.")
@click.option("--planner", default="rrtconnect", show_default=True, help="OMPL planner: rrtconnect, rrtstar, bitstar, prmstar, ...")
@click.option("--space", default="reeds_shepp", show_default=True, help="reeds_shepp (forward and reverse) or dubins.")
@click.option("--turning-radius", type=float, default=None,
              help="[m] (default: the robot's: unicycle 0.5, cars 1.25 x their minimum).")
@click.option("--time-limit", type=float, default=2.0, show_default=True, help="Planning budget [s].")
@click.option("--seed", type=int, default=0, show_default=True, help="OMPL's random seed for this call.")
@click.option("--guide/--no-guide", default=True, show_default=True,
              help="Guided search: a grid shortest path sets subgoals; --no-guide: OMPL over the whole map.")
@click.option("--margin", type=float, default=None,
              help="Clearance to keep from known obstacles [m] (default: the robot's margin).")
@click.option("--max-speed", type=float, default=None, help="[m/s] (default: the robot's limit).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True)
@map_options
def plan(map_file, robot, robot_config, start, goal, problem, planner, space, turning_radius, time_limit, seed, guide,
         margin,
         max_speed, out_dir, cell_size, unknown):
    """Plan on MAP and write trajectory.csv, trajectory.npz, plan.json and plan.png into OUT.

    The robot (model, footprint, margin, turning radius, stabilizer) comes from --robot-config,
    else --robot, else the map's robot block, else the unicycle. Exit code 2 for a bad request
    (start or goal out of bounds or in collision, unknown planner, zero budget, ...), 3 when no plan
    was found within the budget (nothing is written then).
    """
    from nhstab.execution import write_plan
    from nhstab.maps import resolve_poses
    from nhstab.planning import PathOptions, TimingOptions, plan as make_plan

    from nhstab.errors import InputError
    from nhstab.limits import MAX_PLANNER_SEED, check_int
    from nhstab.planning import PLANNABLE

    check_int("--seed", seed, 0, MAX_PLANNER_SEED, "an integer (OMPL's seed)")
    m = load(map_file, cell_size, unknown)
    rob = cli_robot(robot, robot_config, None, m.robot)
    if rob.model.name not in PLANNABLE:
        key = "--robot" if robot else ("--robot-config" if robot_config else f"robot.model (in {map_file})")
        raise InputError(key, "one of " + ", ".join(PLANNABLE) + " (the robots nhstab plans for)", rob.model.name)
    s, g = resolve_poses(m, parse_pose("--start", start), parse_pose("--goal", goal), problem,
                         names=("--start", "--goal", "--problem"))
    path_opts = PathOptions(space=space, turning_radius=turning_radius, planner=planner, time_limit_s=time_limit,
                            seed=seed, margin=margin, guide=guide).for_robot(rob)
    result = make_plan(m, rob, s, g, path_opts, TimingOptions(max_speed=max_speed))
    if not result.ok:
        click.echo(f"nhstab: no plan ({result.status}): {result.message}", err=True)
        return EXIT_NO_PLAN
    write_plan(result, out_dir, m, str(map_file), rob, s, g, path_opts)
    met = result.metrics
    cusps = met["cusps"]
    click.echo(f"plan found for {rob.name}: {met['length_m']:.2f} m, {cusps} cusp{'' if cusps == 1 else 's'}, "
               f"{met['duration_s']:.1f} s, min clearance {met['min_clearance_m']:.3f} m (margin {path_opts.margin:g} m), "
               f"max gain {met['max_gain_norm']:.3g}")
    click.echo(f"wrote {out_dir}/trajectory.csv, trajectory.npz, plan.json, plan.png")
    return 0


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
