"""Options shared by several commands."""

from __future__ import annotations

import click



WINDOW_CHOICES = ("future", "past", "frozen-time")
END_STRATEGY_CHOICES = ("frozen",)


def stabilizer_options(defaults: bool = True):
    """--alpha, --delta, --gamma, --window, --end-strategy. With ``defaults=False`` they default to
    None (meaning: keep the case's own value)."""

    # the choices, spelled out here so that ``nhstab --help`` needs no numpy or scipy
    # (tests/test_cli.py checks them against nhstab.control.WINDOWS and END_STRATEGIES)
    windows, end_strategies = WINDOW_CHOICES, END_STRATEGY_CHOICES

    def deco(f):
        f = click.option("--end-strategy", type=click.Choice(end_strategies), default="frozen" if defaults else None,
                         help="What P is where the window runs off the trajectory: frozen, the last whole "
                              "window carried along the flow (see README; 'switch' was removed).")(f)
        f = click.option("--window", type=click.Choice(windows), default="future" if defaults else None,
                         help="future: P_c = H_c(t, t+delta)^-1 (Proposition 1); frozen-time: the causal law "
                              "(Proposition 1 on A(t), B(t) frozen); past: P_r (Remark 2), NOT stabilizing in "
                              "general, for study only.")(f)
        f = click.option("--gamma", type=float, default=1.0 if defaults else None, help="Gain factor, >= 1/2.")(f)
        f = click.option("--delta", type=float, default=1.0 if defaults else None, help="Window length [s], > 0.")(f)
        f = click.option("--alpha", type=float, default=0.1 if defaults else None, help="Rate parameter, > 0.")(f)
        return f

    return deco


def collect(**values) -> dict:
    """Drop the options left at None."""
    return {k: v for k, v in values.items() if v is not None}
