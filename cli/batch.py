"""``nhstab batch``: Monte Carlo robustness batches (run, replay a trial)."""

from __future__ import annotations

from pathlib import Path

import click

from .options import out_option


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
@out_option("batch", "the batch: its store trials.sqlite and the report (not used with --print-config)")
@click.option("--workers", type=int, default=None, help="Local worker processes (default: the number of cores).")
@click.option("--scheduler", default=None, help="Address of a Dask distributed scheduler, e.g. tcp://10.0.0.5:8786.")
@click.option("--resume", is_flag=True, help="Continue the batch stored in --out: run each missing trial once.")
@click.option("--retry-errors", is_flag=True, help="With --resume: also run again the trials stored with an error.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@click.option("--trials", "trials", type=int, default=None,
              help="Trials per cell instead of the config's, e.g. 2 for a quick look (trial k has the same seed "
                   "whatever the count, so these are the first trials of the full batch).")
@click.option("--print-config", is_flag=True,
              help="Print the effective batch config (YAML: every map's problems, the grid and every run option, "
                   "defaults filled in) and the number of trials, and exit without running (--out is not needed).")
def run_cmd(config_file, out_dir, workers, scheduler, resume, retry_errors, no_progress, trials, print_config):
    """Run every trial of CONFIG (a strict YAML batch config, docs/reference/batch-config.md, or
    example:NAME, a bundled one: `nhstab examples` lists them), committing each to
    OUT/trials.sqlite as it finishes. A trial that fails by error is recorded with its error; the
    batch says how many did, and exits 1 if every trial it ran did. Ctrl-C stops the batch (exit
    code 130; SIGTERM 143, SIGHUP 129) without storing the trials that were running, and ends every
    worker; --resume runs them. Workers also end when this process is killed."""
    import os

    from nhstab.batch.config import load_batch_config
    from nhstab.batch.runner import STORE_NAME, check_scheduler_address, run_batch
    from nhstab.errors import InputError

    if workers is not None and workers < 1:
        raise InputError("--workers", "an integer >= 1", workers)
    if retry_errors and not resume:
        raise InputError("--retry-errors", "used with --resume (it reruns the errors of a stored batch)", "alone")
    if scheduler is not None:
        check_scheduler_address(scheduler)
    config = load_batch_config(config_file)
    if trials is not None:
        config = with_trials(config, trials)
    if print_config:
        import yaml

        click.echo(f"# the effective batch config: {len(config.cells())} cells x {config.trials} trials = "
                   f"{config.n_trials()} trials; options not given are the robot's (margin, space, stabilizer), noise levels not "
                   "given the defaults by state (docs/reference/run-config.md)")
        click.echo(yaml.safe_dump(config.effective(), sort_keys=False), nl=False)
        return 0
    n = config.n_trials()
    click.echo(f"batch {config.name}: {len(config.cells())} cells x {config.trials} trials = {n} trials", err=True)
    try:
        summary = run_batch(config, out_dir, workers=workers or os.cpu_count() or 1, scheduler=scheduler,
                            resume=resume, progress=not no_progress, retry_errors=retry_errors)
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", 2)          # SIGTERM, SIGHUP: BatchSignal; Ctrl-C: SIGINT
        store = out_dir / STORE_NAME
        stored = _stored_count(store)
        how = "interrupted" if signum == 2 else f"stopped by {exc}"
        click.echo(f"nhstab: {how}: {stored} of {n} trials are stored in {store}; the running ones were "
                   f"not; `nhstab batch {config_file} --out {out_dir} --resume` runs the rest", err=True)
        return 128 + signum
    outcomes = ", ".join(f"{k} {v}" for k, v in sorted(summary.outcomes.items(), key=lambda kv: (kv[0] == "error",
                                                                                                 -kv[1], kv[0])))
    click.echo(f"ran {summary.ran} trials in {summary.wall_s:.1f} s ({summary.already_stored} already stored)"
               + (f": {outcomes}" if outcomes else "") + f"; {summary.stored} in {out_dir / STORE_NAME}")
    t = summary.transfer
    if scheduler is not None and t["trials"]:
        click.echo(f"shipped: map bundles {_kb(t['bundles_sent_bytes'])} ({_kb(sum(t['bundle_bytes'].values()))} "
                   f"to each of {t['bundle_copies']} workers); per trial {_kb(t['spec_bytes_per_trial'])} sent, "
                   f"{_kb(t['record_bytes_per_trial'])} received", err=True)
    from nhstab.batch.report import write_report

    files = write_report(out_dir)
    click.echo(f"report: {out_dir / 'report.html'} (and {len(files) - 1} more files)")
    if summary.errors:
        trial_id, message = summary.first_error
        every = summary.errors == summary.ran
        head = (f"failed: all {summary.ran} trials failed by error" if every else
                f"warning: {summary.errors} of {summary.ran} trials failed by error")
        click.echo(f"nhstab: {head}, not by an outcome; the first, {trial_id}: {message} (they are stored as "
                   "errors; --resume --retry-errors runs them again)", err=True)
        if every:
            return 1
    return 0


def with_trials(config, trials: int):
    """``config`` with ``trials`` trials per cell (--trials), checked as the config's own count is."""
    from dataclasses import replace

    from nhstab.errors import InputError
    from nhstab.limits import MAX_BATCH_TRIALS, check_int

    trials = check_int("--trials", trials, 1, MAX_BATCH_TRIALS, "a number of trials per cell")
    cells = config.cell_count()
    if cells * trials > MAX_BATCH_TRIALS:
        raise InputError("--trials", f"at most {MAX_BATCH_TRIALS:,} trials in the batch (cells x trials)",
                         f"{cells:,} cells x {trials} = {cells * trials:,}")
    return replace(config, trials=trials)


def _kb(n) -> str:
    return "-" if n is None else f"{n / 1000:.1f} kB"


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
    """Replay one stored trial with `nhstab run`: writes OUT/run_config.yaml (its exact options), the
    trial's map files under OUT/map/ (so that `nhstab run --config OUT/run_config.yaml` works
    anywhere) and the run's files. STORE is a batch folder or its trials.sqlite (opened read-only).
    The map comes from the store; a store made before stores kept maps needs the map files at the
    path the trial records (with the content the batch used, when the store says which)."""
    from nhstab.batch.replay import prepare_replay

    from .run import execute_and_write

    r = prepare_replay(store_path, trial_id, notify=lambda line: click.echo(line, err=True))
    click.echo(f"replaying {trial_id} (stored status: {r.record['status']}) on {r.map.name} from "
               f"{'the store' if r.from_store else r.bundle.source}", err=True)
    opts = r.options
    return execute_and_write(r.map, str(out_dir / r.map_rel), opts, r.robot, opts.start, opts.goal, out_dir, animate,
                             extra_files=r.files)


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
