"""``nhstab trailer``: the trailer suite (dock bays entered in reverse, 90 degree turns), its plans and the
feedback laws on it."""

from __future__ import annotations

from pathlib import Path

import click

from .options import echo_suite_write, numbers


@click.group("trailer")
def trailer():
    """The trailer suite: maps made from the car with a trailer's geometry (see maps/trailer/suite/SOURCE.md)."""


@trailer.command("suite")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("maps/trailer/suite"), show_default=True, help="Folder for the maps, suite.csv and SOURCE.md.")
@click.option("--check", is_flag=True,
              help="Write nothing: compare the folder with what would be written (exit code 1 if they differ).")
def suite(out_dir, check):
    """Write the trailer suite: one nhstab YAML map per case (dock bays 1.1-1.5 x the rig's width off
    aisles 1.2-2 x its swept path, entered in reverse; 90 degree turns from an aisle into a corridor
    1.2-2 x its swept path), with suite.csv and SOURCE.md (the formula and the table)."""
    from nhstab.trailer_suite import write_suite

    return echo_suite_write(write_suite(out_dir, check=check), out_dir, check, "trailer")


def _print_and_write(text: str, result: dict, out_dir, stem: str) -> int:
    """Print the markdown ``text``; with ``out_dir``, also write it as STEM.md and ``result`` as STEM.json."""
    import json

    from nhstab.records import to_jsonable, write_text

    click.echo(text)
    if out_dir is not None:
        files = [write_text(out_dir / f"{stem}.md", text),
                 write_text(out_dir / f"{stem}.json", json.dumps(to_jsonable(result), indent=1) + "\n")]
        click.echo("wrote " + ", ".join(str(f) for f in files))
    return 0


def _cases(values) -> list[str]:
    return [s.strip() for v in values for s in v.split(",") if s.strip()]


@trailer.command("table")
@click.option("--cases", "cases", multiple=True, metavar="NAME",
              help="Cases of the suite (repeat, or a comma list; default: all).")
@click.option("--seeds", type=int, default=3, show_default=True, help="Seeds 0 .. N-1 per case.")
@click.option("--budget", type=float, default=10.0, show_default=True, help="Search budget per plan [s].")
@click.option("--reach-budget", type=float, default=60.0, show_default=True,
              help="Wall time of `nhstab trailer reach` on each case without a plan [s]; 0 skips it.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Also write table.md and table.json into this folder.")
def table(cases, seeds, budget, reach_budget, out_dir):
    """Plan every case of the suite over seeds and print per case: plans found within the budget,
    median search time, cusps, smallest clearance over every body, largest hitch angle (see
    nhstab.batch.trailer_study); for each case without a plan, whether any plan can exist there
    (`nhstab trailer reach`)."""

    from nhstab.batch.trailer_study import check_cases, plan_table, table_markdown
    from nhstab.execution.config import check_number
    from nhstab.limits import check_int, check_range
    from nhstab.planning.rig_reach import RANGES

    check_cases(_cases(cases), "--cases")
    check_int("--seeds", seeds, 1, 1000, "a number of seeds per case")
    check_number("--budget", budget, 0.0, lo_open=True)
    check_range("--reach-budget", reach_budget, *RANGES["budget_s"], "s")
    result = plan_table(_cases(cases), seeds, budget, progress=lambda s: click.echo(s, err=True),
                        reach_budget_s=reach_budget)
    text = table_markdown(result)
    return _print_and_write(text, result, out_dir, "table")


@trailer.command("reach")
@click.argument("maps", nargs=-1, metavar="[MAP]...")
@click.option("--margin", type=float, default=None, help="Clearance every body keeps [m] (default: the map robot's).")
@click.option("--budget", type=float, default=60.0, show_default=True, help="Wall time per map [s].")
@click.option("--cell", "cell_m", type=float, default=0.1, show_default=True,
              help="Grid cell of the last trailer's axle position [m].")
@click.option("--angle", "angle_deg", type=float, default=2.0, show_default=True,
              help="Grid bin of its heading and of every hitch angle [deg].")
@click.option("--steer-levels", type=int, default=9, show_default=True,
              help="Steering angles per move, spread evenly over +-max_steer.")
@click.option("--step", "step_m", type=float, default=0.2, show_default=True, help="Length of a move [m].")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Also write reach.md and reach.json into this folder.")
def reach(maps, margin, budget, cell_m, angle_deg, steer_levels, step_m, out_dir):
    """Can the rig get from start to goal at all? For each MAP (a map file or example:NAME with a
    car_trailer robot: block; default: every case of the trailer suite), every configuration the rig
    reaches from its start and from its goal, breadth first on a grid, with moves at a steering angle
    set at rest (nhstab.planning.rig_reach). Prints per map: disconnected (one end's configurations ran
    out: no path at this grid), connected (a cell reached from both ends) or undecided (the budget, or the
    cap of 4,000,000 cells, ran out first)."""
    import math

    from nhstab.batch.trailer_study import reach_markdown, reach_table
    from nhstab.execution.config import check_number
    from nhstab.limits import check_int, check_range
    from nhstab.planning.rig_reach import MAX_STEER_LEVELS, RANGES

    # the library's ranges, named by the options (the angle in degrees)
    check_number("--budget", budget, 0.0, lo_open=True)
    check_range("--budget", budget, *RANGES["budget_s"], "s")
    check_range("--cell", cell_m, *RANGES["cell_m"], "m")
    check_range("--angle", angle_deg, *(math.degrees(a) for a in RANGES["angle_rad"]), "deg")
    check_range("--step", step_m, *RANGES["step_m"], "m")
    check_int("--steer-levels", steer_levels, 1, MAX_STEER_LEVELS, "a number of steering angles")
    if margin is not None:
        check_number("--margin", margin, 0.0)
    result = reach_table(list(maps), margin, budget, progress=lambda s: click.echo(s, err=True), cell_m=cell_m,
                         angle_rad=math.radians(angle_deg), steer_levels=steer_levels, step_m=step_m)
    text = reach_markdown(result)
    return _print_and_write(text, result, out_dir, "reach")


@trailer.command("figure")
@click.argument("case")
@click.option("--seed", type=int, default=0, show_default=True, help="The plan's seed.")
@click.option("--budget", type=float, default=10.0, show_default=True, help="Search budget [s].")
@click.option("--out", "out_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="The PNG to write (default: CASE.png in the current folder).")
def figure(case, seed, budget, out_file):
    """Draw a case of the suite: its map, the start and goal rigs, and the plan of SEED with every body
    along it (or, when there is no plan, the map with the reason in the title). Exit code 4 without a plan."""
    from nhstab.batch.trailer_study import case_figure, check_cases
    from nhstab.errors import InputError
    from nhstab.execution.config import check_number
    from nhstab.limits import MAX_SEED, check_int
    from nhstab.records import save_figure

    try:
        name = check_cases([case], "CASE")[0]["name"]
    except InputError as exc:
        raise InputError("CASE", exc.expected, case) from None
    check_int("--seed", seed, 0, MAX_SEED, "a seed")
    check_number("--budget", budget, 0.0, lo_open=True)
    fig, rec = case_figure(name, seed, budget)
    path = save_figure(fig, out_file if out_file is not None else Path(f"{name}.png"), dpi=90)
    if rec["status"] != "ok":
        click.echo(f"{name}, seed {seed}: no plan ({rec['status']}: {rec.get('message', '')}); drew the map into {path}")
        if rec.get("likely_cause"):
            click.echo(rec["likely_cause"])
        return 4
    click.echo(f"{name}, seed {seed}: plan of {rec['length_m']:.1f} m, {rec['cusps']} cusp(s) in {rec['time_s']:.1f} s; "
               f"wrote {path}")
    return 0


@trailer.command("sweep")
@click.argument("config", type=click.Path(dir_okay=False, exists=True, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder for sweep.json.gz and sweep.md.")
@click.option("--workers", type=int, default=1, show_default=True,
              help="Processes over the cases (one BLAS thread each); the result does not depend on it.")
def sweep(config, out_dir, workers):
    """Sweep the gramian law (alpha, delta, gamma, end strategy) against TVLQR on the suite's cases
    that plan, under noise, as CONFIG says (YAML; see the trailer guide): jackknifes, collisions and
    docked trials per law and noise level. Writes sweep.json.gz (the record: compact JSON, gzip-compressed)
    and sweep.md into OUT."""
    from nhstab.batch.trailer_study import load_sweep_config, run_sweep, sweep_markdown
    from nhstab.limits import check_int
    from nhstab.records import write_json_gz, write_text

    check_int("--workers", workers, 1, 64, "a number of worker processes")
    settings = load_sweep_config(config)
    result = run_sweep(settings, progress=lambda s: click.echo(s, err=True), workers=workers)
    files = [write_json_gz(out_dir / "sweep.json.gz", result),
             write_text(out_dir / "sweep.md", sweep_markdown(result))]
    click.echo(f"{result['cases_planned']} of {len(result['cases'])} cases planned; wrote "
               + ", ".join(str(f) for f in files) + f" in {result['wall_s']:.0f} s")
    return 0


@trailer.command("train")
@click.option("--hitch-lengths", default="1.5,3", show_default=True,
              help="The rig's hitch lengths [m], comma-separated: one per trailer (a dolly, then a trailer).")
@click.option("--trials", type=int, default=200, show_default=True, help="Trials per direction and law.")
@click.option("--noise", type=float, default=1.0, show_default=True, help="Noise scale of the trials.")
@click.option("--process-per", type=click.Choice(["second", "metre"]), default="second", show_default=True,
              help="The process disturbance per second (at rest too) or per metre travelled.")
@click.option("--root-seed", type=int, default=2026, show_default=True, help="Root seed of the trials.")
@click.option("--steer-rate", type=float, default=0.07, show_default=True,
              help="The S-curve's steering-rate amplitude [rad/s]: smaller is a gentler curve.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder for train.json.gz and train.md.")
def train(hitch_lengths, trials, noise, process_per, root_seed, steer_rate, out_dir):
    """A car with trailers (default: a dolly and a trailer) along an S-curve, forward and backing its
    trailers along it: whether the gramian law and TVLQR (Q = I, and Q from the outline) stabilize it under
    noise, against the same drive with one trailer. nhstab plans one trailer; this measures the laws on
    more. Writes train.json.gz and train.md into OUT."""
    from nhstab.batch.train_study import train_markdown, train_study
    from nhstab.records import write_json_gz, write_text

    lengths = numbers("--hitch-lengths", hitch_lengths, "numbers separated by commas, e.g. 1.5,3")
    result = train_study(lengths, trials, noise, process_per, root_seed, steer_rate=steer_rate)
    files = [write_json_gz(out_dir / "train.json.gz", result), write_text(out_dir / "train.md", train_markdown(result))]
    click.echo(f"wrote {', '.join(str(f) for f in files)} in {result['wall_s']:.0f} s")
    return 0

