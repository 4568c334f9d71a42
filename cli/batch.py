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
    OUT/trials.sqlite as it finishes. A trial that fails is recorded with its error. Ctrl-C stops the
    batch (exit code 130) without storing the trials that were running; --resume runs them."""
    import os

    from nhstab.batch.config import load_batch_config
    from nhstab.batch.runner import STORE_NAME, check_scheduler_address, run_batch
    from nhstab.errors import InputError

    if workers is not None and workers < 1:
        raise InputError("--workers", "an integer >= 1", workers)
    if scheduler is not None:
        check_scheduler_address(scheduler)
    config = load_batch_config(config_file)
    n = config.n_trials()
    click.echo(f"batch {config.name}: {len(config.cells())} cells x {config.trials} trials = {n} trials", err=True)
    try:
        counts = run_batch(config, out_dir, workers=workers or os.cpu_count() or 1, scheduler=scheduler,
                           resume=resume, progress=not no_progress)
    except KeyboardInterrupt:
        store = out_dir / STORE_NAME
        stored = _stored_count(store)
        click.echo(f"nhstab: interrupted: {stored} of {n} trials are stored in {store}; the running ones were "
                   f"not; `nhstab batch {config_file} --out {out_dir} --resume` runs the rest", err=True)
        return 130
    click.echo(f"ran {counts['ran']} trials in {counts['wall_s']:.1f} s ({counts['already_stored']} already stored); "
               f"{counts['stored']} in {out_dir / STORE_NAME}")
    from nhstab.batch.report import write_report

    files = write_report(out_dir)
    click.echo(f"report: {out_dir / 'report.html'} (and {len(files) - 1} more files)")
    return 0


def _stored_count(path: Path) -> str:
    from nhstab.batch.store import Store
    from nhstab.errors import PipelineError

    try:
        with Store(path) as s:
            return str(s.count())
    except PipelineError:
        return "no"


@batch.command("replay")
@click.argument("store_path", metavar="STORE", type=click.Path(path_type=Path))
@click.argument("trial_id", metavar="TRIAL_ID")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True)
@click.option("--animate", is_flag=True, help="Also write run.gif.")
def replay(store_path, trial_id, out_dir, animate):
    """Replay one stored trial with `nhstab run`: writes OUT/run_config.yaml (its exact options) and
    the run's files. STORE is a batch folder or its trials.sqlite (opened read-only)."""
    import tempfile

    import yaml

    from nhstab.batch.store import Store
    from nhstab.batch.trial import replay_config
    from nhstab.errors import InputError
    from nhstab.execution.config import load_run_config

    from .map import load
    from .run import execute_and_write

    path = store_path / "trials.sqlite" if store_path.is_dir() else store_path
    with Store(path) as store:
        record = store.trial(trial_id)
    if record is None:
        raise InputError("TRIAL_ID", "the id of a stored trial (see the report's CSV)", trial_id)
    try:
        cfg = replay_config(record)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError("TRIAL_ID", "a trial whose stored spec is complete", trial_id,
                         detail=f"{type(exc).__name__}: {exc}") from None
    text = "# replays trial " + trial_id + " of " + str(path) + "\n" + yaml.safe_dump(cfg, sort_keys=False)
    with tempfile.TemporaryDirectory(prefix="nhstab-replay-") as tmp:
        cfg_path = Path(tmp) / "run_config.yaml"
        cfg_path.write_text(text, encoding="utf-8")
        extra, opts = load_run_config(cfg_path)
    cell = record["spec"]["cell_spec"]
    m = load(extra["map"], cell["cell_size"], None)
    from nhstab.robot import resolve_robot

    click.echo(f"replaying {trial_id} (stored status: {record['status']})", err=True)
    robot = resolve_robot(opts.robot, m.robot, source="run config")
    return execute_and_write(m, str(extra["map"]), opts, robot, opts.start, opts.goal, out_dir, animate,
                             extra_files={"run_config.yaml": text})


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
