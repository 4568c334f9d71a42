"""Entry point: the ``nhstab`` group, and turning errors into one-line messages."""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import warnings

import click
from nhstab._version import __version__
from nhstab.errors import InputError, PipelineError, SingularGramianError

#: exit code for bad input (arguments, options, files, unusable trajectories)
EXIT_INPUT = 2
#: exit code for a numerical failure in a computation
EXIT_FAILURE = 1


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """nhstab's own warnings as one line on stderr (each text once); others as Python prints them."""
    from nhstab.errors import NhstabWarning

    if issubclass(category, NhstabWarning):
        click.echo(f"nhstab: warning: {_one_line(message)}", err=True)
    else:
        _default_showwarning(message, category, filename, lineno, file, line)


_default_showwarning = warnings.showwarning


def _on_sigint(signum, frame):
    """Ctrl-C: KeyboardInterrupt, as Python's own handler, except while the files of a finished
    computation are written (:func:`nhstab.interrupts.holding_interrupts`: they are completed, and the
    command then exits 130), and inside an FCL callback, where the exception would be printed and
    lost: there the collision query raises it when FCL returns."""
    from nhstab.interrupts import hold_interrupt

    if hold_interrupt():
        return
    from nhstab.collision import defer_interrupt

    if not defer_interrupt(frame):
        raise KeyboardInterrupt


@contextlib.contextmanager
def _sigint_handler():
    """:func:`_on_sigint` while a command runs, where Ctrl-C would raise KeyboardInterrupt (not where
    SIGINT is ignored, as in a process a non-interactive shell starts in the background, nor outside
    the main thread)."""
    main = threading.current_thread() is threading.main_thread()
    if not main or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield
        return
    from nhstab.interrupts import interrupt_held

    interrupt_held()                  # none held from an earlier command in this process
    signal.signal(signal.SIGINT, _on_sigint)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        interrupt_held()


class NhstabGroup(click.Group):
    """A click group whose errors are one line on stderr with a non-zero exit code, no traceback;
    nhstab's warnings are one line each."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        from nhstab.errors import NhstabWarning

        with warnings.catch_warnings(), _sigint_handler():    # restored on exit (CliRunner runs in-process)
            warnings.showwarning = _show_warning
            warnings.simplefilter("once", NhstabWarning)
            self._main(args, prog_name, complete_var, **extra)

    def _main(self, args, prog_name, complete_var, **extra):
        try:
            rv = super().main(args=args, prog_name=prog_name or "nhstab", complete_var=complete_var,
                              standalone_mode=False, **extra)
        except click.exceptions.UsageError as exc:
            ctx = exc.ctx
            where = f" ({ctx.command_path})" if ctx is not None else ""
            click.echo(f"nhstab: error{where}: {_one_line(exc.format_message())}", err=True)
            sys.exit(EXIT_INPUT)
        except (InputError, SingularGramianError) as exc:
            click.echo(f"nhstab: error: {_one_line(exc)}", err=True)
            sys.exit(EXIT_INPUT)
        except PipelineError as exc:
            click.echo(f"nhstab: failed: {_one_line(exc)}", err=True)
            sys.exit(EXIT_FAILURE)
        except click.exceptions.Abort:
            click.echo("nhstab: aborted", err=True)
            sys.exit(130)
        except click.ClickException as exc:
            click.echo(f"nhstab: error: {_one_line(exc.format_message())}", err=True)
            sys.exit(exc.exit_code)
        except OSError as exc:
            click.echo(f"nhstab: error: {_one_line(exc)}", err=True)
            sys.exit(EXIT_INPUT)
        sys.exit(rv if isinstance(rv, int) else 0)


@click.group(cls=NhstabGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="nhstab")
def cli():
    """Plan, stabilize and stress-test nonholonomic robots (Walsh et al. 1992 composite controller)."""


def _register():
    from . import bench, gains, paper
    from .batch import batch
    from .examples import examples
    from .export import export_group
    from .map import map_group
    from .parking import parking
    from .plan import plan, sweep
    from .robot import robot_group
    from .run import run
    from .schema import schema
    from .trailer import trailer
    from .tubes import tubes

    cli.add_command(examples)
    cli.add_command(map_group)
    cli.add_command(plan)
    cli.add_command(run)
    cli.add_command(batch)
    cli.add_command(sweep)
    cli.add_command(paper.paper)
    cli.add_command(gains.gains)
    cli.add_command(bench.bench)
    cli.add_command(parking)
    cli.add_command(trailer)
    cli.add_command(tubes)
    cli.add_command(robot_group)
    cli.add_command(export_group)
    cli.add_command(schema)


_register()


def main():  # console script
    cli.main()


if __name__ == "__main__":  # pragma: no cover
    main()
