"""``nhstab map show|info``: look at a map file."""

from __future__ import annotations

import json
from pathlib import Path

import click

from .options import robot_options


def parse_pose(name: str, text: str | None):
    from nhstab.errors import InputError

    if text is None:
        return None
    parts = text.replace(" ", "").split(",")
    try:
        values = [float(v) for v in parts]
    except ValueError:
        raise InputError(name, "x,y,theta (metres, metres, radians)", text) from None
    if not 3 <= len(values) <= 12 or not all(abs(v) < float("inf") for v in values):
        raise InputError(name, "x,y,theta (metres, metres, radians), finite; a car with trailers may add "
                         "their headings theta1,..., a car its steering angle (the full state, phi = 0)", text)
    from nhstab.limits import check_headings

    check_headings(name, values)
    return tuple(values)


def safe_file_name(name: str, fallback: str = "map", limit: int = 100) -> str:
    """A default output name made from text a file gave (a map's ``name``): one path component of
    letters, digits, '.', '-' and '_' only (anything else, path separators included, becomes '_'),
    no leading dot, at most ``limit`` characters; ``fallback`` (sanitised too) if nothing is left."""
    import re

    def clean(text: str) -> str:
        out = re.sub(r"[^A-Za-z0-9._-]+", "_", str(text)).strip("._-")
        return out[:limit].rstrip("._-")

    return clean(name) or clean(fallback) or "map"


def map_options(f):
    f = click.option("--unknown", type=click.Choice(["occupied", "free"]), default=None,
                     help="ROS maps: how unknown cells count (default occupied).")(f)
    f = click.option("--cell-size", type=float, default=None, help="Moving AI maps: metres per cell (default 1).")(f)
    return f


def load(path, cell_size, unknown):
    from nhstab.errors import user_keys
    from nhstab.maps import load_map

    options = {}
    if cell_size is not None:
        options["cell_size"] = cell_size
    if unknown is not None:
        options["unknown"] = unknown
    with user_keys({"example": ("MAP", str(path)), "cell_size": "--cell-size", "unknown": "--unknown"}):
        return load_map(path, **options)


def pose_keys(m, start, goal, problem=None, config_start=None, config_goal=None) -> dict:
    """For :func:`nhstab.errors.user_keys`: how errors name a command's start and goal: the option that
    gave them (--start, --goal, --problem), else the run config's key, else the map file's."""
    if problem is not None:
        return {"start": "--problem", "goal": "--problem"}
    source = m.source or m.name
    return {key: flag if given is not None else key if config is not None else f"{source}: {key}"
            for key, flag, given, config in (("start", "--start", start, config_start),
                                             ("goal", "--goal", goal, config_goal))}


def _arr(p):
    return None if p is None else p.as_array()


def _footprint(m, robot, robot_config=None):
    from .options import cli_robot

    return cli_robot(robot, robot_config, None, m.robot, m).footprint


@click.group("map")
def map_group():
    """Look at map files: ROS map_server YAML, Moving AI .map, Bench-MR .svg, nhstab YAML."""


@map_group.command("info")
@click.argument("map_file", metavar="MAP", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@robot_options
@map_options
def info(map_file, as_json, robot, robot_config, cell_size, unknown):
    """Size, resolution, obstacle counts and free fraction of MAP."""
    from nhstab.report.maps import map_summary

    m = load(map_file, cell_size, unknown)
    summary = map_summary(m, _footprint(m, robot, robot_config))
    if as_json:
        from nhstab.records import to_jsonable

        click.echo(json.dumps(to_jsonable(summary), indent=2))
        return 0
    w, h = summary["size_m"]
    click.echo(f"{m.name}  ({m.source})")
    click.echo(f"  bounds      x [{m.bounds[0]:.3f}, {m.bounds[2]:.3f}]  y [{m.bounds[1]:.3f}, {m.bounds[3]:.3f}]  "
               f"({w:.2f} x {h:.2f} m)")
    for g in summary["grids"]:
        click.echo(f"  grid        {g['cells'][1]} x {g['cells'][0]} cells at {g['resolution_m']:g} m, "
                   f"{g['occupied_cells']} occupied, {g['unknown_cells']} unknown, {g['merged_boxes']} merged boxes")
    click.echo(f"  obstacles   {summary['known_obstacles']} known shapes, {summary['unknown_obstacles']} unknown")
    click.echo(f"  free        {100 * summary['free_fraction']:.1f} % of the bounds "
               f"(measured on {summary['free_fraction_cell_m']:.3g} m cells)")
    if summary["problems"]:
        click.echo(f"  problems    {summary['problems']} start/goal pairs")
    for note in summary["notes"]:
        click.echo(f"  note        {note}")
    for key in ("start", "goal"):
        if summary[key] is not None:
            x, y, th = summary[key]
            click.echo(f"  {key:11s} ({x:.3f}, {y:.3f}, {th:.3f} rad), clearance {summary[key + '_clearance_m']:.3f} m")
    return 0


@map_group.command("show")
@click.argument("map_file", metavar="MAP", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="PNG to write (default: MAP's name with .png in the current folder).")
@click.option("--start", default=None, help="Start: the pose x,y,theta (a car_trailer may add theta1), or the robot's full state with phi = 0 (default: the map's).")
@click.option("--goal", default=None, help="Goal: the pose x,y,theta (a car_trailer may add theta1), or the robot's full state with phi = 0 (default: the map's).")
@robot_options
@click.option("--problems", type=click.IntRange(min=0), default=0, show_default=True,
              help="Also draw this many of the map's start/goal problems.")
@map_options
def show(map_file, out, start, goal, robot, robot_config, problems, cell_size, unknown):
    """Draw MAP: known obstacles solid, unknown dashed, bounds, start and goal with the footprint."""
    from nhstab.collision import check_poses
    from nhstab.errors import InputError
    from nhstab.records import save_figure
    from nhstab.report.maps import map_figure

    if out is not None and (not str(out).strip() or str(out) in (".", "..") or str(out).endswith(("/", "\\"))):
        raise InputError("--out", "the path of a PNG file to write", str(out))
    from .options import cli_robot

    m = load(map_file, cell_size, unknown)
    rob = cli_robot(robot, robot_config, None, m.robot)
    fp = rob.footprint
    s = parse_pose("--start", start) or _arr(m.start)
    g = parse_pose("--goal", goal) or _arr(m.goal)
    # the rule of every start and goal (Robot.configuration), for the robots nhstab plans for
    if "x" in rob.model.state_names and "theta" in rob.model.state_names:
        s = None if s is None else rob.configuration(s, "--start" if start is not None else "start")
        g = None if g is None else rob.configuration(g, "--goal" if goal is not None else "goal")
    from nhstab.errors import user_keys

    with user_keys(pose_keys(m, start, goal)):
        clear = check_poses(m, fp, {"start": None if s is None else s[:3], "goal": None if g is None else g[:3]})
    out = out or Path(safe_file_name(m.name, fallback=Path(str(map_file)).stem) + ".png")
    fig = map_figure(m, start=s, goal=g, footprint=fp, problems=problems, robot=rob,
                     title=f"{m.name}: {fp.label}" + "".join(f", {k} clearance {v:.2f} m" for k, v in clear.items()))
    save_figure(fig, out)
    click.echo(f"wrote {out}")
    return 0


#: the bundled maps drawn by ``nhstab map gallery``: (path under maps/, loader options, drawing options)
GALLERY = [
    ("ours/parking_lot.yaml", {}, {}),
    ("ours/warehouse_corridor.yaml", {}, {}),
    ("ours/cluttered_room.yaml", {}, {}),
    ("nav2/depot.yaml", {}, {}),
    ("bench-mr/polygon_mazes/parking3.svg", {}, {"problems": 5, "robot": "rwd_car"}),
    ("movingai/64room_000.map", {"cell_size": 0.5}, {"problems": 20}),
]


@map_group.command("gallery")
@click.option("--maps", "maps_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="The bundled maps folder (default: the one installed with nhstab).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("results/maps"),
              show_default=True)
def gallery(maps_dir, out_dir):
    """Draw a selection of the bundled maps into OUT (the committed results/maps)."""
    from nhstab.errors import InputError
    from nhstab.maps import load_map
    from nhstab.records import save_figure
    from nhstab.report.maps import map_figure

    if maps_dir is None:
        from nhstab.examples import data_root

        maps_dir = data_root()
    if not maps_dir.is_dir():
        raise InputError("--maps", "a folder holding the bundled maps", str(maps_dir))
    for rel, load_opts, draw in GALLERY:
        m = load_map(maps_dir / rel, **load_opts)
        fp = _footprint(m, draw.get("robot"))
        out = out_dir / f"{Path(rel).stem}.png"
        save_figure(map_figure(m, start=_arr(m.start), goal=_arr(m.goal), footprint=fp,
                               problems=draw.get("problems", 0), title=f"{m.name}: {fp.label}"), out)
        click.echo(f"wrote {out}")
    return 0
