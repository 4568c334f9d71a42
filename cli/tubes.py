"""``nhstab tubes``: the error-tube study (predicted tubes against the run loop, and the gain grid)."""

from __future__ import annotations

from pathlib import Path

import click


@click.group()
def tubes():
    """Error tubes: how far the stabilized robot strays, checked against Monte Carlo."""


@tubes.command()
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("results/tubes"),
              show_default=True)
@click.option("--trials", type=int, default=200, show_default=True, help="Trials per cell (2 to 5,000).")
@click.option("--seed", "root_seed", type=int, default=2026, show_default=True, help="Root seed of the trials.")
@click.option("--gains/--no-gains", default=True, show_default=True, help="Also the --gains auto grid and its check.")
def study(out_dir, trials, root_seed, gains):
    """The tube study: unicycle and rwd_car on two bundled maps each, gramian and TVLQR, noise x0.5, x1,
    x2; writes study.json.gz (the record, gzip-compressed), study.md and figures into OUT (see
    nhstab.batch.tube_study)."""
    from nhstab.batch.tube_study import write_study
    from nhstab.limits import MAX_SEED, MAX_STUDY_TRIALS, check_int

    check_int("--trials", trials, 2, MAX_STUDY_TRIALS, "a number of trials per cell")
    check_int("--seed", root_seed, 0, MAX_SEED, "a seed")
    files = write_study(out_dir, trials, root_seed, gains=gains, progress=lambda s: click.echo(s, err=True))
    click.echo(f"wrote {len(files)} files into {out_dir} (study.md, study.json.gz, figures)")
    return 0


@tubes.command()
@click.argument("out_dir", metavar="DIR", type=click.Path(file_okay=False, exists=True, path_type=Path),
                default=Path("results/tubes"))
def redraw(out_dir):
    """Redraw a study's report without rerunning its trials: study.md from DIR/study.json.gz (or an
    uncompressed DIR/study.json; default results/tubes), and each case's plan figure (plan_ROBOT_MAP.png)
    from its first plan and tube made again, drawn only when they are those the study records (same
    cusps; length, duration, clearance and tube clearance equal); one line says why each other figure is
    left as it is. The std and coverage figures need the trials' series: nhstab tubes study draws them.
    Exit code 1 when a figure is left."""
    from nhstab.batch.tube_study import redraw_study

    files, left = redraw_study(out_dir, progress=lambda s: click.echo(s, err=True))
    for line in left:
        click.echo(line, err=True)
    click.echo("wrote " + ", ".join(str(f) for f in files))
    return 1 if left else 0
