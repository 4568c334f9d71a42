"""``nhstab robot``: robot descriptions from other tools (``from-nav2``: a Nav2 parameters file)."""

from __future__ import annotations

from pathlib import Path

import click


@click.group("robot")
def robot_group():
    """Robot descriptions: read one from another tool's files."""


@robot_group.command("from-nav2")
@click.argument("params", metavar="PARAMS.yaml", type=click.Path(path_type=Path))
@click.option("-o", "--out", "out_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the robot YAML here (default: print it).")
@click.option("--model", type=click.Choice(["unicycle", "rwd_car", "fwd_car"]), default=None,
              help="The model (default: inferred from the planner: SmacPlannerHybrid or an ackermann "
                   "SmacPlannerLattice gives rwd_car, any other planner unicycle).")
@click.option("--wheelbase", type=float, default=None,
              help="A car's wheelbase [m]; its max_steer is then atan(L / R) for the planner's minimum turning "
                   "radius R (default: the model's max_steer, and L = R tan(max_steer)).")
@click.option("--margin", type=float, default=None, help="Planning margin [m] (default: the model's).")
def from_nav2(params, out_file, model, wheelbase, margin):
    """Read the robot of a Nav2 parameters file (nav2_params.yaml) and write it as an nhstab robot YAML.

    The footprint comes from the costmaps (footprint string or robot_radius, plus footprint_padding),
    the model, planning space (space: dubins for a forward-only DUBIN motion model) and minimum turning
    radius from the Smac planner (SmacPlannerHybrid's motion_model_for_search and
    minimum_turning_radius), the speed limits from the controller and the
    velocity smoother. One line per value says where it came from. The same file is read directly by
    --robot-config nav2:PARAMS.yaml on plan, run and map.
    """
    import yaml
    from nhstab.errors import InputError
    from nhstab.nav2 import read_nav2_robot
    from nhstab.records import write_text

    try:
        got = read_nav2_robot(params, model=model, wheelbase=wheelbase, margin=margin)
    except InputError as exc:
        if exc.argument in ("wheelbase", "margin"):
            raise exc.renamed(f"--{exc.argument}") from None
        raise
    rob = got.robot
    head = [f"nhstab robot read from the Nav2 parameters file {params.name} (nhstab robot from-nav2)"]
    head += got.lines
    if got.space == "dubins":
        head.append("forward only: space dubins, which nhstab plan and run use unless --space or planning.space "
                    "says otherwise")
    text = "".join(f"# {h}\n" for h in head) + yaml.safe_dump({"robot": rob.spec()}, sort_keys=False,
                                                               default_flow_style=None)
    if out_file is None:
        click.echo(text, nl=False)
        return 0
    write_text(out_file, text)
    for line in got.lines:
        click.echo(f"nav2: {line}")
    click.echo(f"wrote {out_file} ({rob.model.name}, footprint {rob.footprint.label}, minimum turning radius "
               f"{rob.min_turning_radius:.4g} m)")
    return 0
