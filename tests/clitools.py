"""Helpers the command-line tests share: invoking nhstab in-process, and the one-line error contract."""
import os

from click.testing import CliRunner
from nhstab.cli.main import cli


def invoke(*args, cwd=None):
    """``nhstab ARGS`` in this process (click's runner), from ``cwd`` if given."""
    old = os.getcwd()
    if cwd is not None:
        os.chdir(cwd)
    try:
        return CliRunner().invoke(cli, [str(a) for a in args])
    finally:
        os.chdir(old)


def one_line(res, code: int, *needles: str) -> str:
    """The command exited with ``code`` and printed one error line (no traceback, no Python error
    that escaped as one) holding the needles; returns that line."""
    assert res.exit_code == code, (res.exit_code, res.output, res.exception)
    assert "Traceback" not in res.output and not isinstance(res.exception, (AttributeError, TypeError, IndexError))
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("nhstab:")]
    assert len(lines) == 1, res.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def only_line(res, code: int, *needles: str) -> None:
    """The command exited with ``code`` and wrote exactly one non-empty line to stderr, holding the
    needles, and no traceback."""
    assert res.exit_code == code, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in res.output, res.output
    for n in needles:
        assert n in lines[0], lines[0]
