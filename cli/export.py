"""``nhstab export``: plans and runs in other tools' formats (``ros2-path``: a ROS 2 nav_msgs/Path)."""

from __future__ import annotations

import math
from pathlib import Path

import click


@click.group("export")
def export_group():
    """Write a plan or a run in another tool's format."""


@export_group.command("ros2-path")
@click.argument("folder", metavar="FOLDER", type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--out", "out_file", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="The message file (FILE.yaml, or FILE.json with --format json).")
@click.option("--format", "fmt", type=click.Choice(["yaml", "json"]), default="yaml", show_default=True,
              help="yaml: for ros2 topic pub; json: the same fields, with the directions in FILE.segments.json.")
@click.option("--frame", "frame_id", default="map", show_default=True, help="header.frame_id of the path and poses.")
@click.option("--stamp", type=float, default=0.0, show_default=True,
              help="Time of the first pose [s]; each pose is stamped with it plus its time along the trajectory.")
@click.option("--stride", type=int, default=1, show_default=True,
              help="Keep every N-th sample (and always the first, the last and the ends of every forward or "
                   "reverse run).")
def ros2_path(folder, out_file, fmt, frame_id, stamp, stride):
    """Write the trajectory of a plan or run FOLDER as a ROS 2 nav_msgs/msg/Path.

    A plan folder (nhstab plan --out) gives its nominal, a run folder (nhstab run --out) the robot's
    simulated trajectory. Publish the YAML with
    ros2 topic pub --once /plan nav_msgs/msg/Path "$(cat FILE)" (up to 128 KiB, one shell argument), or
    with --yaml-file FILE where ros2 topic pub has that option. Coordinates are the map's: the ROS map
    frame for a map_server map. nav_msgs/Path has no direction of travel: the cusps and the forward and
    reverse segments are listed in the YAML's comments (or FILE.segments.json).
    """
    from nhstab.ros_path import SHELL_ARG_MAX, export_path

    got = export_path(folder, out_file, fmt=fmt, frame_id=frame_id, stamp=stamp, stride=stride)
    segs = got["segments"]
    rev = sum(1 for s in segs if s[2] < 0)
    click.echo(f"wrote {', '.join(str(f) for f in got['files'])}: nav_msgs/Path of the {got['kind']}, "
               f"{got['poses']} poses in frame {frame_id!r}, {len(got['cusps'])} cusp(s), "
               f"{rev} reverse segment(s), {got['bytes'] / 1024:.1f} KiB")
    if fmt == "yaml" and got["bytes"] > SHELL_ARG_MAX:
        click.echo(f"note: {got['bytes'] / 1024:.0f} KiB is more than one shell argument holds on Linux "
                   f"({SHELL_ARG_MAX // 1024} KiB), so \"$(cat FILE)\" fails: publish with --yaml-file FILE "
                   f"where ros2 topic pub has it, or export with --stride "
                   f"{math.ceil(got['bytes'] * stride / (0.9 * SHELL_ARG_MAX))} or more")
    return 0
