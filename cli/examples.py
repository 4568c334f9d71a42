"""``nhstab examples``: the maps and scenarios bundled with nhstab (use them as ``example:NAME``)."""

from __future__ import annotations

import json

import click


@click.command()
@click.option("--json", "as_json", is_flag=True, help="Print JSON (name, path, format, robot, kind, description).")
def examples(as_json):
    """List the bundled maps and scenarios, then the bundled batch and run configs. Any command that
    takes a map accepts example:NAME, e.g. `nhstab run example:depot_blocked_aisle --out run1`; so do
    `nhstab batch example:NAME` and `nhstab run --config example:NAME` for the configs (--json lists
    the maps only)."""
    from nhstab.examples import list_configs, list_examples

    items = list_examples()
    if as_json:
        click.echo(json.dumps([e.as_dict() for e in items], indent=2))
        return 0
    width = max(len(e.name) for e in items)
    fmt_w = max(len(e.format) for e in items)
    rob_w = max(len(e.robot) for e in items)
    kind = None
    for e in items:
        if e.kind != kind:
            kind = e.kind
            click.echo({"scenario": "Scenarios (start, goal, obstacles the robot's map lacks): nhstab run example:NAME",
                        "problems": "Maps with start/goal problems: add --problem N",
                        "map": "Maps: give --start and --goal unless the map has them"}[kind])
        click.echo(f"  {e.name:<{width}}  {e.format:<{fmt_w}}  {e.robot:<{rob_w}}  {e.description}")
    configs = list_configs()
    for kind, head in (("batch_config", "Batch configs: nhstab batch example:NAME --out DIR (--trials N for a quick "
                                        "look, --print-config to see every option)"),
                       ("run_config", "Run configs: nhstab run --config example:NAME --out DIR")):
        rows = [c for c in configs if c.kind == kind]
        if rows:
            click.echo(head)
            for c in rows:
                click.echo(f"  {c.name:<{width}}  {c.description}")
    return 0
