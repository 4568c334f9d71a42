"""Ctrl-C while the files of a finished computation are written.

A command that has finished its work (a run's simulation, a plan) and is writing its files should
not lose them to a Ctrl-C. Inside :func:`holding_interrupts`, a SIGINT handler that asks
:func:`hold_interrupt` (the command line's does) keeps the interrupt instead of raising
KeyboardInterrupt; the files are completed, and :func:`interrupt_held` then tells the command that
one arrived (the command line exits 130). Without such a handler (a library caller keeping Python's
default one), nothing changes. This module imports nothing heavy: the command line's handler uses it.
"""

from __future__ import annotations

import contextlib

_HOLD = {"depth": 0, "pending": False}


@contextlib.contextmanager
def holding_interrupts():
    """Hold interrupts inside the block (nested blocks hold too)."""
    _HOLD["depth"] += 1
    try:
        yield
    finally:
        _HOLD["depth"] -= 1


def hold_interrupt() -> bool:
    """For a SIGINT handler: inside :func:`holding_interrupts`, keep the interrupt and return True;
    elsewhere return False (the handler raises as usual)."""
    if _HOLD["depth"] > 0:
        _HOLD["pending"] = True
        return True
    return False


def interrupt_held(clear: bool = True) -> bool:
    """Did an interrupt arrive inside :func:`holding_interrupts` since the last call that cleared it?"""
    pending = _HOLD["pending"]
    if clear:
        _HOLD["pending"] = False
    return pending
