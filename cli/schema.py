"""``nhstab schema``: the JSON Schemas of nhstab's YAML formats (maps, robots, run and batch configs)."""

from __future__ import annotations

from pathlib import Path

import click
from nhstab.yaml_keys import FORMATS, SCHEMA_DIR


@click.command()
@click.argument("name", required=False, type=click.Choice(FORMATS))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Write every schema into this folder as NAME.schema.json.")
@click.option("--check", "check_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Write nothing: compare this folder's schemas with what --out writes (exit code 1 if they differ).")
def schema(name, out_dir, check_dir):
    """Print the JSON Schema (draft 2020-12) of one YAML format (NAME: map, robot, run-config,
    batch-config), or with --out write all four. The package ships them (the folder printed without
    arguments); the loaders take their keys from them. Built from the code's definitions: the run
    config's dataclasses and defaults, the models' parameters, the controllers, windows, planners,
    spaces and tube kinds."""
    from nhstab.schema import build_schemas, schema_text, stale_schemas, write_schemas

    if check_dir is not None:
        stale = stale_schemas(check_dir)
        if stale:
            click.echo(", ".join(stale))
            click.echo(f"{check_dir} is not what `nhstab schema --out {check_dir}` writes", err=True)
            return 1
        click.echo(f"{check_dir} is up to date")
        return 0
    if out_dir is not None:
        files = write_schemas(out_dir)
        click.echo(f"wrote {len(files)} schemas into {out_dir}")
        return 0
    if name is not None:
        click.echo(schema_text(build_schemas()[name]), nl=False)
        return 0
    click.echo(f"shipped in {SCHEMA_DIR}:")
    for fmt in FORMATS:
        click.echo(f"  {fmt}.schema.json")
    return 0
