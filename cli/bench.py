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
              show_default=True, help="Folder for bench.json and summary.md (when run without a subcommand).")
@click.pass_context
def bench(ctx, out_dir):
    """Run every benchmark (no subcommand) or one of them. Writes JSON."""
    if ctx.invoked_subcommand is not None:
        return 0
    from nhstab.bench import BENCHMARKS, summary_markdown
    from nhstab.records import write_json, write_text

    results = {}
    for name, fn in BENCHMARKS.items():
        click.echo(f"running {name} ...", err=True)
        results[name] = fn()
        write_json(out_dir / "bench.json", results)      # keep what is done if a later one fails
    write_text(out_dir / "summary.md", summary_markdown(results))
    click.echo(summary_markdown(results))
    click.echo(f"wrote {out_dir / 'bench.json'} and {out_dir / 'summary.md'}", err=True)
    return 0


#: the benchmark subcommands: name -> help (the functions live in nhstab.bench.BENCHMARKS)
SUBCOMMANDS = {
    "startup": "Import time: `nhstab --help` against `python -c pass`, whole processes.",
    "gains": "Gain schedule: N = 1e3, 1e4, 1e5 on the Hilare sinusoid, and the naive method at N = 1e3.",
    "collision": "FCL world build time and car pose checks per second on the Moving AI 512x512 and nav2 depot maps.",
    "planning": "Time to a feasible, stabilizable nominal over 20 fixed start/goal pairs on two maps, two robots, "
                "and the scale series on the Moving AI NewYork_1_512 scenarios.",
    "run": "Composite controller: replan latency on the depot and warehouse scenarios; cost of a control update.",
    "batch": "Batch throughput: vectorised Hilare trials on one and two workers against the competent per-trial "
             "baseline (a naive one as an extra row), full map trials.",
    "tube": "Error tube: its time against the plan's on the bundled scenarios, and a per-step loop baseline.",
}


def _subcommand(name: str, help_text: str):
    @bench.command(name, help=help_text)
    @click.option("--out", type=click.Path(dir_okay=False, path_type=Path),
                  default=Path(f"results/bench/{name}.json"), show_default=True)
    def run(out):
        from nhstab.bench import BENCHMARKS

        _emit(BENCHMARKS[name](), out)
        return 0

    return run


for _name, _help in SUBCOMMANDS.items():
    _subcommand(_name, _help)
