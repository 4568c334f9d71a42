"""``nhstab paper``: reproduce the seed paper's simulations."""

from __future__ import annotations

from pathlib import Path

import click

from .options import collect, stabilizer_options


@click.command()
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("results/paper"),
              show_default=True, help="Folder for the figures, summary.json.gz and summary.md.")
@click.option("--case", "cases", multiple=True, metavar="NAME",
              help="Run only this case (repeatable). Default: all. See --list.")
@click.option("--list", "list_cases", is_flag=True, help="List the cases and exit.")
@stabilizer_options(defaults=False)
def paper(out_dir, cases, list_cases, alpha, delta, gamma, window, end_strategy):
    """Reproduce the paper's simulations: Heisenberg line and point, Hilare sinusoid and circle, FWD
    car parallel parking (gamma = 1/2, and gamma = 1 beside it).

    Stabilizer options given here override every selected case's own values (recorded in the summary).
    """
    from nhstab.errors import user_keys
    from nhstab.paper import CASES, run_paper

    if list_cases:
        for case in CASES.values():
            click.echo(f"{case.name:24s} {case.title}")
        return 0
    overrides = collect(alpha=alpha, delta=delta, gamma=gamma, window=window, end_strategy=end_strategy)
    # the options given name the errors about their values
    with user_keys({"case": "--case", **{key: "--" + key.replace("_", "-") for key in overrides}}):
        summaries = run_paper(out_dir, list(cases) or None, overrides,
                              progress=lambda name: click.echo(f"running {name} ...", err=True))
    for s in summaries:
        ratio = s.get("final_to_initial_ratio")
        extra = f"||e(T)||/||e(0)|| = {ratio:.3g}" if ratio is not None else s.get("message", "")
        click.echo(f"{s['case']:24s} {s['status']:17s} {extra}")
    click.echo(f"wrote {out_dir / 'summary.json.gz'}, {out_dir / 'summary.md'} and the figures in {out_dir}/")
    return 0
