"""``nhstab plan``: a feasible, collision-free, stabilizable nominal trajectory on a map."""

from __future__ import annotations

from pathlib import Path

import click

from .map import load, map_options, parse_pose

#: exit code when the request is valid but no plan was found within the budget
EXIT_NO_PLAN = 3


@click.command()
@click.argument("map_file", metavar="MAP", type=click.Path(path_type=Path))
@click.option("--robot", default=None, help="unicycle, rwd_car or fwd_car (default: the map's, else unicycle).")
@click.option("--start", default=None, help="Start pose x,y,theta (default: the map's).")
@click.option("--goal", default=None, help="Goal pose x,y,theta (default: the map's).")
@click.option("--problem", type=int, default=None, help="Use the map's start/goal problem with this index.")
@click.option("--planner", default="rrtconnect", show_default=True, help="OMPL planner: rrtconnect, rrtstar, bitstar, prmstar, ...")
@click.option("--space", default="reeds_shepp", show_default=True, help="reeds_shepp (forward and reverse) or dubins.")
@click.option("--turning-radius", type=float, default=None, help="[m] (default: the robot's minimum; unicycle 0.5).")
@click.option("--time-limit", type=float, default=2.0, show_default=True, help="Planning budget [s].")
@click.option("--seed", type=int, default=0, show_default=True, help="OMPL's random seed for this call.")
@click.option("--margin", type=float, default=0.1, show_default=True, help="Clearance to keep from known obstacles [m].")
@click.option("--max-speed", type=float, default=None, help="[m/s] (default: the robot's limit).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True)
@map_options
def plan(map_file, robot, start, goal, problem, planner, space, turning_radius, time_limit, seed, margin, max_speed,
         out_dir, cell_size, unknown):
    """Plan on MAP and write trajectory.csv, trajectory.npz, plan.json and plan.png into OUT.

    Exit code 2 for a bad request (start or goal out of bounds or in collision, unknown planner, zero
    budget, ...), 3 when no plan was found within the budget (nothing is written then).
    """
    from nhstab.execution import write_plan
    from nhstab.geometry import default_footprint
    from nhstab.maps import resolve_poses
    from nhstab.models import make_model
    from nhstab.planning import PathOptions, TimingOptions, default_turning_radius, plan as make_plan

    from nhstab.errors import InputError
    from nhstab.limits import MAX_PLANNER_SEED, check_int
    from nhstab.planning import PLANNABLE

    check_int("--seed", seed, 0, MAX_PLANNER_SEED, "an integer (OMPL's seed)")
    m = load(map_file, cell_size, unknown)
    name = robot or (m.robot or {}).get("model") or "unicycle"
    if name not in PLANNABLE:
        key = "--robot" if robot else f"robot.model of {map_file}"
        raise InputError(key, "one of " + ", ".join(PLANNABLE) + " (the robots nhstab plans for)", name)
    model = make_model(name)
    fp = default_footprint(name)
    s, g = resolve_poses(m, parse_pose("--start", start), parse_pose("--goal", goal), problem,
                         names=("--start", "--goal", "--problem"))
    path_opts = PathOptions(space=space, turning_radius=default_turning_radius(model) if turning_radius is None else turning_radius, planner=planner,
                            time_limit_s=time_limit, seed=seed, margin=margin)
    result = make_plan(m, model, fp, s, g, path_opts, TimingOptions(max_speed=max_speed))
    if not result.ok:
        click.echo(f"nhstab: no plan ({result.status}): {result.message}", err=True)
        return EXIT_NO_PLAN
    write_plan(result, out_dir, m, str(map_file), model, fp, s, g, path_opts)
    met = result.metrics
    cusps = met["cusps"]
    click.echo(f"plan found: {met['length_m']:.2f} m, {cusps} cusp{'' if cusps == 1 else 's'}, "
               f"{met['duration_s']:.1f} s, min clearance {met['min_clearance_m']:.3f} m, "
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
