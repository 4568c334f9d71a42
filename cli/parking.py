"""``nhstab parking``: the parking suite (parallel slots, perpendicular and angled bays)."""

from __future__ import annotations

from pathlib import Path

import click


@click.group("parking")
def parking():
    """The parking suite of issue 11: maps made from the cars' geometry (see maps/parking/SOURCE.md)."""


@parking.command("suite")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("maps/parking"),
              show_default=True, help="Folder for the maps, suite.csv and SOURCE.md.")
@click.option("--check", is_flag=True,
              help="Write nothing: compare the folder with what would be written (exit code 1 if they differ).")
def suite(out_dir, check):
    """Write the parking suite: one nhstab YAML map per case (parallel slots at 0.9-1.4 x L1,
    perpendicular bays at four aisle widths, 45 and 60 degree bays), for the default rwd_car and a
    long van, with suite.csv and SOURCE.md (the formulas and the table)."""
    from nhstab.parking import write_suite

    result = write_suite(out_dir, check=check)
    if check:
        bad = {k: v for k, v in result.items() if v}
        if bad:
            for key, names in bad.items():
                click.echo(f"{key}: {', '.join(names)}")
            click.echo(f"{out_dir} is not what `nhstab parking suite --out {out_dir}` writes", err=True)
            return 1
        click.echo(f"{out_dir} is up to date")
        return 0
    click.echo(f"wrote {len(result['written'])} files into {out_dir}")
    return 0


@parking.command("table")
def table():
    """Print the suite's cases: car, kind, slot length or aisle width, and its reference (L1 or the
    aisle's swept-path estimate)."""
    from nhstab.parking import suite as cases

    for c in cases():
        what = "slot" if c.kind == "parallel" else "aisle"
        ref = "L1" if c.kind == "parallel" else "swept-path estimate"
        click.echo(f"{c.name:<34} {c.car:<8} {c.kind:<14} {what} {c.size_m:6.3f} m = {c.factor:g} x {ref} "
                   f"{c.reference_m:.3f} m")
    return 0


@parking.command("figure")
@click.option("--car", default="rwd_car", show_default=True, help="The suite's car: rwd_car or van.")
@click.option("--seeds", default="0,1,2", show_default=True, help="Seeds to try per slot, in order (comma list).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("results/parking/tightest_parallel"), show_default=True)
def figure(car, seeds, out_dir):
    """Run the composite controller (default noise, gramian law) on the car's parallel slots,
    tightest first, and write the first run that parks (run.json, trajectory.csv, run_map.png,
    run_tracking.png) and tried.json (every attempt before it) into OUT. Exit code 4 if none parks."""
    from nhstab.errors import InputError
    from nhstab.execution import write_run
    from nhstab.parking import tightest_parallel_run
    from nhstab.records import write_json

    try:
        seed_list = [int(s) for s in seeds.split(",") if s.strip()]
    except ValueError:
        raise InputError("--seeds", "integers separated by commas, e.g. 0,1,2", seeds) from None
    if not seed_list or min(seed_list) < 0:
        raise InputError("--seeds", "non-negative integers separated by commas, e.g. 0,1,2", seeds)
    row, seed, result, tried = tightest_parallel_run(car, seed_list, progress=lambda s: click.echo(s, err=True))
    write_json(out_dir / "tried.json", {"car": car, "seeds": seed_list, "tried": tried,
                                        "chosen": None if row is None else {"map": row["name"], "seed": seed,
                                                                            "factor": row["factor"]}})
    if result is None:
        click.echo(f"no parallel slot of the {car} was parked with seeds {seeds}; see {out_dir / 'tried.json'}")
        return 4
    files = write_run(result, out_dir, f"example:{row['name']}")
    click.echo(f"{row['name']} ({row['factor']:g} x L1, slot {row['size_m']:.2f} m), seed {seed}: {result.message}")
    click.echo("wrote " + ", ".join(str(f) for f in files) + f", {out_dir / 'tried.json'}")
    return 0
