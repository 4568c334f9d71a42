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
    import numpy as np

    from pipeline.errors import InputError
    from pipeline.geometry import default_footprint
    from pipeline.models import make_model
    from pipeline.planning import PathOptions, TimingOptions, default_turning_radius, plan as make_plan, pose_columns
    from pipeline.records import save_figure, write_json
    from pipeline.report.plans import plan_figure
    from pipeline.trajectory_io import write_trajectory

    m = load(map_file, cell_size, unknown)
    name = robot or (m.robot or {}).get("model") or "unicycle"
    model = make_model(name)
    fp = default_footprint(name)
    if problem is not None:
        if not (0 <= problem < len(m.problems)):
            raise InputError("--problem", f"an index in [0, {len(m.problems)})", problem)
        s, g = m.problems[problem].start.as_array(), m.problems[problem].goal.as_array()
    else:
        s = parse_pose("--start", start) or (m.start.as_array() if m.start else None)
        g = parse_pose("--goal", goal) or (m.goal.as_array() if m.goal else None)
    if s is None or g is None:
        raise InputError("--start/--goal", "poses (the map gives none)", None)
    path_opts = PathOptions(space=space, turning_radius=default_turning_radius(model) if turning_radius is None else turning_radius, planner=planner,
                            time_limit_s=time_limit, seed=seed, margin=margin)
    result = make_plan(m, model, fp, s, g, path_opts, TimingOptions(max_speed=max_speed))
    if not result.ok:
        click.echo(f"nhstab: no plan ({result.status}): {result.message}", err=True)
        return EXIT_NO_PLAN
    nom = result.nominal
    out_dir.mkdir(parents=True, exist_ok=True)
    write_trajectory(out_dir / "trajectory.csv", nom)
    write_trajectory(out_dir / "trajectory.npz", nom)
    inputs = {"map": str(map_file), "robot": model.describe(), "footprint": fp.describe(),
              "start": list(map(float, s)), "goal": list(map(float, g)), "path_options": path_opts.__dict__,
              "feasibility_residual_m": nom.feasibility_residual()}
    write_json(out_dir / "plan.json", {"status": result.status, "message": result.message, "inputs": inputs,
                                       "metrics": result.metrics})
    poses = nom.x[:, pose_columns(model)]
    cusps = result.metrics["cusps"]
    cusp_text = f"{cusps} cusp" + ("" if cusps == 1 else "s")
    fig = plan_figure(m, poses, np.sign(nom.u[:, 0]), fp, s, g,
                      title=f"{m.name}: {name}, {result.metrics['length_m']:.1f} m, {cusp_text}, "
                            f"min clearance {result.metrics['min_clearance_m']:.2f} m")
    save_figure(fig, out_dir / "plan.png")
    click.echo(f"plan found: {result.metrics['length_m']:.2f} m, {cusp_text}, "
               f"{result.metrics['duration_s']:.1f} s, min clearance {result.metrics['min_clearance_m']:.3f} m, "
               f"max gain {result.metrics['max_gain_norm']:.3g}")
    click.echo(f"wrote {out_dir}/trajectory.csv, trajectory.npz, plan.json, plan.png")
    return 0


@click.command()
@click.option("--map", "map_file", type=click.Path(path_type=Path), default=Path("maps/ours/parking_lot.yaml"),
              show_default=True)
@click.option("--seed", type=int, default=1, show_default=True)
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("results/planning"),
              show_default=True)
def sweep(map_file, seed, out_dir):
    """The stabilizer-parameter sweep behind the per-robot defaults: writes sweep.json and sweep.md."""
    from pipeline.planning.sweep import sweep as run_sweep
    from pipeline.planning.sweep import sweep_markdown
    from pipeline.records import write_json, write_text

    result = run_sweep(map_file, seed)
    write_json(out_dir / "sweep.json", result)
    write_text(out_dir / "sweep.md", sweep_markdown(result))
    click.echo(sweep_markdown(result))
    click.echo(f"chosen: {result['chosen']}")
    return 0
