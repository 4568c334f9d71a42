"""``nhstab bench``: benchmarks that write JSON."""

from __future__ import annotations

import json
from pathlib import Path

import click


def _emit(result: dict, out: Path):
    from nhstab.records import to_jsonable, write_json

    write_json(out, result)
    click.echo(json.dumps(to_jsonable(result), indent=2))
    click.echo(f"wrote {out}", err=True)


@click.group(invoke_without_command=True)
@click.option("--out-dir", type=click.Path(file_okay=False, path_type=Path), default=Path("results/bench"),
              show_default=True, help="Folder for bench.json.gz (gzip-compressed JSON) and summary.md (when run "
                                       "without a subcommand).")
@click.option("--only", default=None, metavar="NAME[,NAME...]",
              help="Run only these benchmarks and merge their results into OUT_DIR/bench.json.gz (the others "
                   "kept as they were; an uncompressed bench.json there is read and replaced), then "
                   "rewrite summary.md from the merged file.")
@click.pass_context
def bench(ctx, out_dir, only):
    """Run every benchmark (no subcommand) or one of them. Writes JSON."""
    from nhstab.errors import InputError

    if ctx.invoked_subcommand is not None:
        if only is not None:
            raise InputError("--only", "no subcommand with it (it selects among all the benchmarks)",
                             f"--only {only} with {ctx.invoked_subcommand}")
        return 0
    from nhstab.bench import BENCHMARKS, previous_results, select_benchmarks, summary_markdown
    from nhstab.records import write_json_gz, write_text

    names = select_benchmarks(only)
    results = {} if only is None else previous_results(out_dir)
    for name in names:
        fn = BENCHMARKS[name]
        click.echo(f"running {name} ...", err=True)
        results[name] = fn()
        write_json_gz(out_dir / "bench.json.gz", results, indent=2)      # keep what is done if a later one fails
    write_text(out_dir / "summary.md", summary_markdown(results))
    click.echo(summary_markdown(results))
    click.echo(f"wrote {out_dir / 'bench.json.gz'} and {out_dir / 'summary.md'}", err=True)
    return 0


#: the benchmark subcommands: name -> help (the functions live in nhstab.bench.BENCHMARKS)
SUBCOMMANDS = {
    "startup": "Import time: `nhstab --help` against `python -c pass`, whole processes.",
    "gains": "Gain schedule: N = 1e3, 1e4, 1e5 on the Hilare sinusoid, and the naive method at N = 1e3.",
    "collision": "FCL world build time and car pose checks per second on the Moving AI 512x512 and nav2 depot maps.",
    "planning": "Time to a feasible, stabilizable nominal over 20 fixed start/goal pairs on two maps, two robots, "
                "and the scale series on the Moving AI NewYork_1_512 scenarios.",
    "parking": "Planning on the parking suite: success within 5 s over 10 seeds, time, cusps, duration and gain "
               "against their bounds, per case (a few minutes; longer where searches fail and use their budget).",
    "run": "Composite controller: replan latency on the depot and warehouse scenarios; cost of a control update.",
    "batch": "Batch throughput: vectorised Hilare trials on one and two workers against the competent per-trial "
             "baseline (a naive one as an extra row), full map trials.",
    "tube": "Error tube: the linear tube's time against the plan's on the bundled scenarios, and a per-step loop "
            "baseline; the default (auto) tube, linear or sampled, against the plan on those scenarios and on "
            "parking cases, its parts, and the sampled tube against a rollout-by-rollout baseline.",
    "polygons": "Polygon checks up to the accepted maximum of 10,000 vertices: GEOS simplicity test, footprint "
                "parser, YAML map load and collision world, raster fill, on a star and a comb of long teeth at "
                "1,250-10,000 vertices, with scaling exponents and the vectorised pairwise baseline.",
    "trailer": "Planning on the trailer suite's cases at 1.2x widths and above: plans within 10 s over 3 seeds and the "
               "median time, against the trailer-axle search alone (a few minutes).",
    "geometry": "2-D geometry against shapely on real maps: each operation the library hands to shapely against "
                "the hand-written numpy baseline, each it keeps against the shapely construction, with the ratio "
                "and the largest difference between the answers.",
}


#: options of some subcommands beyond --out, passed to bench_<name> as keywords when given
EXTRA_OPTIONS = {
    "parking": [
        click.option("--seeds", type=int, default=None, help="Seeds per case (default 10)."),
        click.option("--budget", "budget_s", type=float, default=None, help="Planning budget per call [s] (default 5)."),
        click.option("--case", "cases", multiple=True,
                     help="Only this case (repeatable; names as in `nhstab parking table`)."),
    ],
    "tube": [
        click.option("--case", "cases", multiple=True,
                     help="Parking cases of the auto-tube rows (repeatable; names as in `nhstab parking table`, "
                          "all, or none; default all)."),
        click.option("--auto-repeats", type=int, default=None, help="Plan-and-tube pairs per auto-tube row (default 3)."),
        click.option("--baseline-rollouts", type=int, default=None,
                     help="Rollouts of the sampled tube's baseline, extrapolated to N (default 40)."),
    ],
    "trailer": [
        click.option("--seeds", type=int, default=None, help="Seeds per case (default 3)."),
        click.option("--budget", "budget_s", type=float, default=None, help="Planning budget per call [s] (default 10)."),
    ],
    "polygons": [
        click.option("--size", "sizes", type=click.IntRange(6, 10_000), multiple=True,
                     help="Vertices per polygon (repeatable; default 1250, 2500, 5000, 10000)."),
    ],
}


def _subcommand(name: str, help_text: str):
    def run(out, **extra):
        from nhstab.bench import BENCHMARKS

        kwargs = {k: v for k, v in extra.items() if v not in (None, ())}
        if name in EXTRA_OPTIONS:
            kwargs["progress"] = lambda line: click.echo(line, err=True)
        _emit(BENCHMARKS[name](**kwargs), out)
        return 0

    for opt in reversed(EXTRA_OPTIONS.get(name, [])):
        run = opt(run)
    run = click.option("--out", type=click.Path(dir_okay=False, path_type=Path),
                       default=Path(f"results/bench/{name}.json"), show_default=True)(run)
    return bench.command(name, help=help_text)(run)


for _name, _help in SUBCOMMANDS.items():
    _subcommand(_name, _help)
