"""``nhstab parking``: the parking suite (parallel slots, perpendicular and angled bays)."""

from __future__ import annotations

import csv
from pathlib import Path

import click

from .options import echo_suite_write, numbers


@click.group("parking")
def parking():
    """The parking suite: maps made from the cars' geometry (see maps/parking/SOURCE.md)."""


@parking.command("suite")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder for the maps, suite.csv and SOURCE.md (default: maps/parking; required with "
                   "--robot-config).")
@click.option("--check", is_flag=True,
              help="Write nothing: compare the folder with what would be written (exit code 1 if they differ).")
@click.option("--robot-config", "robot_config", type=click.Path(path_type=Path), default=None,
              help="The suite of one's own car: a robot description (YAML, as a map's robot: block) of an "
                   "rwd_car with a rectangular footprint; its margin, else 0.1 m.")
@click.option("--name", "car_name", default=None,
              help="With --robot-config: the car's name in the map names (default: the file's name key).")
def suite(out_dir, check, robot_config, car_name):
    """Write the parking suite: one nhstab YAML map per case (parallel slots at 0.9-1.4 x L1,
    perpendicular bays at four aisle widths, 45 and 60 degree bays), for the default rwd_car and a
    long van, with suite.csv and SOURCE.md (the formulas and the table). With --robot-config, the same
    cases sized for that car (study them with `nhstab parking study --suite OUT`)."""
    from nhstab.errors import InputError
    from nhstab.parking import own_car, write_suite
    from nhstab.safe_io import load_yaml_file

    if robot_config is None:
        if car_name is not None:
            raise InputError("--name", "given with --robot-config (the name of one's own car)", car_name)
        out = out_dir if out_dir is not None else Path("maps/parking")
        return echo_suite_write(write_suite(out, check=check), out, check, "parking")
    if out_dir is None:
        raise InputError("--out", "a folder for the suite of one's own car (with --robot-config; the bundled "
                         "suite's maps/parking is not overwritten)", "nothing")
    from nhstab.parking import read_suite_csv

    spec = load_yaml_file(robot_config, "--robot-config", "robot description (YAML)")
    specs = own_car(spec, f"{Path(robot_config).name}: robot", car_name)
    existing = Path(out_dir) / "suite.csv"
    if existing.is_file():             # never write over another car's suite (the bundled one, say)
        try:
            others = sorted({r["car"] for r in read_suite_csv(existing)} - set(specs))
            held = "it holds the suite of " + ", ".join(others)
        except (KeyError, ValueError, TypeError, UnicodeDecodeError, csv.Error):
            others, held = [existing.name], "it holds a suite.csv that is not a parking suite's"
        if others:
            raise InputError("--out", "a new folder or one holding this car's suite", str(out_dir), detail=held)
    command = (f"nhstab parking suite --robot-config {robot_config}" + (f" --name {car_name}" if car_name else "")
               + f" --out {out_dir}")
    try:
        result = write_suite(out_dir, check=check, specs=specs, command=command)
    except InputError as exc:        # a layout that cannot be made for this car: say it of the car given
        raise InputError(f"{Path(robot_config).name}: robot", "a car the suite's layouts can be sized for",
                         next(iter(specs)), detail=" ".join(str(exc).split())) from None
    return echo_suite_write(result, out_dir, check, "parking", command)


@parking.command("table")
def table():
    """Print the suite's cases, one row each under a header: map name, car, kind, what is sized (the
    slot's length or the aisle's width), its size, the factor and the reference it multiplies (L1 or
    the aisle's swept-path estimate)."""
    from nhstab.parking import suite as cases

    head = ("map", "car", "kind", "measure", "size [m]", "factor", "reference", "reference [m]")
    rows = [(c.name, c.car, c.kind, "slot length" if c.kind == "parallel" else "aisle width", f"{c.size_m:.3f}",
             f"{c.factor:g}", "L1" if c.kind == "parallel" else "swept-path estimate", f"{c.reference_m:.3f}")
            for c in cases()]
    widths = [max(len(r[i]) for r in (head, *rows)) for i in range(len(head))]
    numeric = {4, 5, 7}
    for r in (head, *rows):
        click.echo("  ".join(v.rjust(w) if i in numeric else v.ljust(w)
                             for i, (v, w) in enumerate(zip(r, widths))).rstrip())
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
    from nhstab.interrupts import holding_interrupts, interrupt_held

    with holding_interrupts():      # from here a Ctrl-C does not lose the finished run: its files are completed
        files = write_run(result, out_dir, f"example:{row['name']}")
    click.echo(f"{row['name']} ({row['factor']:g} x L1, slot {row['size_m']:.2f} m), seed {seed}: {result.message}")
    click.echo("wrote " + ", ".join(str(f) for f in files) + f", {out_dir / 'tried.json'}")
    if interrupt_held():
        click.echo("nhstab: interrupted after the run ended; its files are complete", err=True)
        return 130
    return 0


#: the study's tube figures by default: the tightest parallel slots of both cars (results/ stays small)
FIGURE_MAPS = ("parallel_rwd_car_090", "parallel_rwd_car_100", "parallel_van_100", "perpendicular_van_aisle110")


@parking.command("study")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder for study.json.gz, study.md and the figures (default: results/parking/study; with "
                   "--suite, SUITE/study).")
@click.option("--suite", "suite_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="A suite of one's own car (a folder written by nhstab parking suite --robot-config) instead "
                   "of the bundled one.")
@click.option("--trials", type=int, default=50, show_default=True, help="Trials per cell (1 to 5,000).")
@click.option("--mc-factor", type=int, default=10, show_default=True,
              help="The tube check's Monte Carlo: this many times the sampled tube's N rollouts per cell (with 1 "
                   "no tube can be rebuilt from the runs, and the check's 'below' part is undetermined).")
@click.option("--maps", "maps", multiple=True, metavar="NAME",
              help="Maps of the suite (repeat, or a comma list; default: all, 28 in the bundled suite).")
@click.option("--noise", default="0.5,1,2", show_default=True, help="Noise scales (comma list).")
@click.option("--controllers", default="gramian,tvlqr", show_default=True, help="Feedback laws (comma list).")
@click.option("--root-seed", type=int, default=2026, show_default=True,
              help="Root seed of the trials (the Monte Carlo's is this + 1).")
@click.option("--plan-seed", type=int, default=0, show_default=True, help="The plans' seed (nhstab run --seed).")
@click.option("--workers", type=int, default=2, show_default=True,
              help="Processes over the maps (one BLAS thread each); the result does not depend on it.")
@click.option("--fit/--no-fit", default=True, show_default=True,
              help="Plan as `nhstab run --fit` (an uncertified plan is changed until its tube certifies, the best "
                   "kept) or as plain `nhstab run`.")
@click.option("--figures", "figure_maps", default=",".join(FIGURE_MAPS), show_default=True,
              help="Maps whose tube figure is drawn (comma list; 'all' or 'none').")
@click.option("--process-per", type=click.Choice(["second", "metre"]), default="second", show_default=True,
              help="The process disturbance acts per second (at rest too) or per metre the car travels (none at "
                   "rest), as nhstab run --process-per: for the plans, their tubes and every trial.")
@click.option("--gains", type=click.Choice(["default", "auto"]), default="default", show_default=True,
              help="The gramian law's gains: the car's defaults, or auto: per plan, as nhstab run --gains auto "
                   "(alpha, delta, gamma from a grid by the plan's linear tube).")
@click.option("--tvlqr-q", type=click.Choice(["identity", "footprint"]), default="identity", show_default=True,
              help="TVLQR's Q: the identity, or footprint: weights from how far a state error moves the car's "
                   "outline (as a run config's controller q: footprint).")
def study(out_dir, suite_dir, trials, mc_factor, maps, noise, controllers, root_seed, plan_seed, workers, fit,
          figure_maps, process_per, gains, tvlqr_q):
    """The parking study: per suite map one plan (the first of `nhstab run example:NAME --seed PLAN_SEED --fit`);
    per controller and noise level its error tube and verdict, trials of the run loop (collisions,
    goal reached) and the tube held to an independent Monte Carlo (coverage, conservatism). Writes
    study.json.gz (the record: compact JSON, gzip-compressed), study.md and figures into OUT (see
    nhstab.batch.parking_study)."""
    from nhstab.batch.parking_study import (
        check_controllers,
        check_levels,
        check_maps,
        run_parking_study,
        study_markdown,
        success_figure,
        tube_figure,
    )
    from nhstab.limits import MAX_SEED, MAX_STUDY_TRIALS, check_int
    from nhstab.records import save_figure, write_json_gz, write_text

    check_int("--trials", trials, 1, MAX_STUDY_TRIALS, "a number of trials per cell")
    check_int("--mc-factor", mc_factor, 1, 100, "a factor of the tube's rollouts")
    check_int("--root-seed", root_seed, 0, MAX_SEED - 1, "a seed")
    check_int("--plan-seed", plan_seed, 0, MAX_SEED, "a seed")
    check_int("--workers", workers, 1, 64, "a number of worker processes")
    names = [s.strip() for m in maps for s in m.split(",") if s.strip()]
    rows = check_maps(names, "--maps", suite_dir)
    if out_dir is None:
        out_dir = Path("results/parking/study") if suite_dir is None else suite_dir / "study"
    levels = check_levels(numbers("--noise", noise, "noise scales separated by commas, e.g. 0.5,1,2"), "--noise")
    ctrls = check_controllers([s.strip() for s in controllers.split(",") if s.strip()], "--controllers")
    figs = [s.strip() for s in figure_maps.split(",") if s.strip()]
    if suite_dir is not None and figure_maps == ",".join(FIGURE_MAPS):
        # one's own car: the figures of its two tightest parallel slots among the maps studied
        figs = [r["name"] for r in rows if r["kind"] == "parallel" and r["factor"] <= 1.0] or ["none"]
    elif figs not in (["all"], ["none"]):
        check_maps(figs, "--figures", suite_dir)
    from nhstab.execution.config import ControllerOptions, NoiseOptions, PlanningOptions, RunOptions

    options = RunOptions(planning=PlanningOptions(fit=fit), noise=NoiseOptions(process_per=process_per),
                         controller=ControllerOptions(gains=gains, q=None if tvlqr_q == "identity" else tvlqr_q))
    result, curves = run_parking_study(trials, mc_factor, names, levels, ctrls, root_seed, plan_seed, options=options,
                                       workers=workers, progress=lambda s: click.echo(s, err=True), suite=suite_dir)
    # the numbers first: a figure that fails must not lose an hour's study
    # the record compact and gzip-compressed (the whole suite at three noise levels: 0.7 MB of compact JSON, 0.13 MB
    # compressed), so that results/ stays small
    files = [write_json_gz(out_dir / "study.json.gz", result),
             write_text(out_dir / "study.md", study_markdown(result))]
    files.append(save_figure(success_figure(result), out_dir / "success.png", dpi=90))
    for case in result["cases"]:
        if case.get("cells") and (figs == ["all"] or case["map"] in figs):
            files.append(save_figure(tube_figure(curves, result, case["map"]), out_dir / f"tube_{case['map']}.png",
                                     dpi=80))
    tg = result["targets"]
    click.echo("targets: " + "; ".join(
        f"{k} not evaluated (no cell at x{result['criteria']['target_noise']:g})" if not t.get("evaluated", True)
        else f"{k} {'met' if t['met'] else 'NOT met'} ({len(t['failing'])} failing)" for k, t in tg.items()))
    click.echo(f"wrote {len(files)} files into {out_dir} (study.md, study.json.gz, figures) in "
               f"{result['wall_s']:.0f} s")
    return 0
