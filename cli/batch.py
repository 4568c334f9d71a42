"""``nhstab batch``: Monte Carlo robustness batches (run, replay a trial)."""

from __future__ import annotations

from pathlib import Path

import click


class _DefaultToRun(click.Group):
    """``nhstab batch CONFIG ...`` means ``nhstab batch run CONFIG ...``."""

    def parse_args(self, ctx, args):
        if args and args[0] not in self.commands and not args[0].startswith("-"):
            args = ["run", *args]
        return super().parse_args(ctx, args)


@click.group(cls=_DefaultToRun)
def batch():
    """Monte Carlo batches over maps, robots, controllers and noise: `nhstab batch CONFIG --out DIR`."""


@batch.command("run")
@click.argument("config_file", metavar="CONFIG", type=click.Path(path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder of the batch: trials.sqlite (and the report).")
@click.option("--workers", type=int, default=None, help="Local worker processes (default: the number of cores).")
@click.option("--scheduler", default=None, help="Address of a Dask distributed scheduler, e.g. tcp://10.0.0.5:8786.")
@click.option("--resume", is_flag=True, help="Continue the batch stored in --out: run each missing trial once.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
def run_cmd(config_file, out_dir, workers, scheduler, resume, no_progress):
    """Run every trial of CONFIG (strict YAML; see pipeline/batch/config.py), committing each to
    OUT/trials.sqlite as it finishes. A trial that fails is recorded with its error."""
    import os

    from nhstab.batch.config import load_batch_config
    from nhstab.batch.runner import run_batch
    from nhstab.errors import InputError

    if workers is not None and workers < 1:
        raise InputError("--workers", "an integer >= 1", workers)
    config = load_batch_config(config_file)
    n = len(config.trial_specs())
    click.echo(f"batch {config.name}: {len(config.cells())} cells x {config.trials} trials = {n} trials", err=True)
    counts = run_batch(config, out_dir, workers=workers or os.cpu_count() or 1, scheduler=scheduler, resume=resume,
                       progress=not no_progress)
    click.echo(f"ran {counts['ran']} trials in {counts['wall_s']:.1f} s ({counts['already_stored']} already stored); "
               f"{counts['stored']} in {out_dir / 'trials.sqlite'}")
    from nhstab.batch.report import write_report

    files = write_report(out_dir)
    click.echo(f"report: {out_dir / 'report.html'} (and {len(files) - 1} more files)")
    return 0


@batch.command("replay")
@click.argument("store_path", metavar="STORE", type=click.Path(path_type=Path))
@click.argument("trial_id", metavar="TRIAL_ID")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True)
@click.option("--animate", is_flag=True, help="Also write run.gif.")
def replay(store_path, trial_id, out_dir, animate):
    """Replay one stored trial with `nhstab run`: writes OUT/run_config.yaml (its exact options) and
    the run's files. STORE is a batch folder or its trials.sqlite."""
    import yaml

    from nhstab.batch.store import Store
    from nhstab.batch.trial import replay_config
    from nhstab.errors import InputError
    from nhstab.execution.config import load_run_config
    from nhstab.records import write_text

    from .map import load
    from .run import execute_and_write

    path = store_path / "trials.sqlite" if store_path.is_dir() else store_path
    with Store(path) as store:
        record = store.trial(trial_id)
    if record is None:
        raise InputError("TRIAL_ID", "the id of a stored trial (see the report's CSV)", trial_id)
    cfg = replay_config(record)
    cfg_path = write_text(out_dir / "run_config.yaml", "# replays trial " + trial_id + " of " + str(path) + "\n"
                          + yaml.safe_dump(cfg, sort_keys=False))
    extra, opts = load_run_config(cfg_path)
    cell = record["spec"]["cell_spec"]
    m = load(extra["map"], cell["cell_size"], None)
    from nhstab.robot import resolve_robot

    click.echo(f"replaying {trial_id} (stored status: {record['status']})", err=True)
    robot = resolve_robot(opts.robot, m.robot, source="run config")
    return execute_and_write(m, str(extra["map"]), opts, robot, opts.start, opts.goal, out_dir, animate)


@batch.command("report")
@click.argument("store_path", metavar="STORE", type=click.Path(path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to write the report (default: the store's folder).")
def report(store_path, out_dir):
    """Write report.html, report.md, trials.csv and figures/ from a batch store (STORE: the batch
    folder or its trials.sqlite). Every number comes from the store."""
    from nhstab.batch.report import write_report

    files = write_report(store_path, out_dir)
    click.echo("wrote " + ", ".join(str(f) for f in files))
    return 0
