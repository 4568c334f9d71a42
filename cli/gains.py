"""``nhstab gains``: the gain schedule along a nominal trajectory read from a file."""

from __future__ import annotations

from pathlib import Path

import click

from .options import stabilizer_options

#: the models' stabilizer defaults as ``--help`` shows them (spelled out so that ``--help`` needs no
#: numpy; tests/cli/test_cli_lines.py checks them against nhstab.robot.MODEL_DEFAULTS)
DEFAULTS_HELP = ("unicycle alpha 0.2, delta 2; rwd_car alpha 0.1, delta 6, end-strategy extend, cusps split; "
                 "fwd_car alpha 0.2, delta 3, end-strategy extend, cusps split; heisenberg alpha 1, delta 1; "
                 "car_trailer alpha 0.02, delta 15, gamma 2; else gamma 1, window future, end-strategy frozen, "
                 "cusps across")


def _parse_params(items) -> dict:
    from nhstab.errors import InputError

    params = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError("--param", "KEY=VALUE", item)
        try:
            params[key.strip()] = float(value)
        except ValueError:
            raise InputError(f"--param {key}", "a number", value) from None
    return params


@click.command()
@click.argument("trajectory", type=click.Path(path_type=Path))
@click.option("--model", "model_name", required=True, help="Robot model: heisenberg, unicycle, fwd_car, rwd_car.")
@click.option("--param", "params", multiple=True, metavar="KEY=VALUE", help="Model parameter, e.g. wheelbase=2.5.")
@stabilizer_options(defaults=False)
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder for gains.npz and gains.json.")
def gains(trajectory, model_name, params, alpha, delta, gamma, window, end_strategy, out_dir):
    """Compute the gramian gain schedule along the nominal in TRAJECTORY (CSV or NPZ).

    The stabilizer options default to the model's built-in robot's, the ones nhstab plan and run use:
    {defaults}.

    Writes gains.npz (t, P, K, H eigenvalues, gamma, x0, u0, and the linearisation A(t), B(t) at the
    samples) and gains.json (options and diagnostics:
    p_m, p_M, the guaranteed rate rate_bound = 3 alpha of the future window (docs/theory/control-law.md)
    beside the paper's printed 2 alpha p_m / p_M (rate_bound_printed), the certified Lyapunov rates, the smallest
    eigenvalue of H and where). The past window has no guarantee (it is not stabilizing in general).
    """
    from nhstab.control import StabilizerOptions, compute_schedule
    from nhstab.errors import user_keys
    from nhstab.models import make_model
    from nhstab.records import OutputFolder
    from nhstab.trajectory_io import read_trajectory

    given = _parse_params(params)
    # the options the user wrote name the errors: the model's parameters are --param KEY
    names = {"model": "--model", f"{model_name} parameter": "--param",
             **{f"{model_name}.{k}": f"--param {k}" for k in given}}
    with user_keys(names):
        model = make_model(model_name, **given)
    from nhstab.robot import MODEL_DEFAULTS

    chosen = {**MODEL_DEFAULTS[model.name].get("stabilizer", {}),
              **{k: v for k, v in (("alpha", alpha), ("delta", delta), ("gamma", gamma), ("window", window),
                                   ("end_strategy", end_strategy)) if v is not None}}
    stab = {"alpha": "--alpha", "delta": "--delta", "gamma": "--gamma", "window": "--window",
            "end_strategy": "--end-strategy"}
    with user_keys(stab):
        opts = StabilizerOptions(**chosen).validated()
    nominal = read_trajectory(trajectory, model)
    with user_keys(stab):
        schedule = compute_schedule(nominal, opts)
    d = {**schedule.diagnostics, **schedule.diagnose()}             # with the certified Lyapunov rates
    A, B = model.linearize(schedule.nominal.x, schedule.nominal.u)    # (N, n, n), (N, n, m) at the samples
    with OutputFolder(out_dir, "gains", owned=("gains.npz", "gains.json")) as out:
        out.write_npz("gains.npz", t=schedule.t, P=schedule.P, K=schedule.K, H_eigenvalues=schedule.H_eigenvalues,
                      gamma=schedule.gamma, x0=schedule.nominal.x, u0=schedule.nominal.u, A=A, B=B)
        out.write_json("gains.json", {"trajectory": str(trajectory), **model.describe(),
                                      "stabilizer": {k: opts_record(v) for k, v in chosen.items()}, **d})
    if d["rate_bound"] is not None:
        rates = (f"guaranteed rate 3 alpha = {d['rate_bound']:.4g} 1/s (the paper's printed 2 alpha p_m/p_M = "
                 f"{d['rate_bound_printed']:.4g} 1/s)")
    else:
        rates = (f"no guaranteed rate for the {opts.window} window (certified Lyapunov rate of V: min "
                 f"{d['lyapunov_rate_min']:.4g}, mean {d['lyapunov_rate_mean']:.4g} 1/s)")
    click.echo(f"{model.name}: alpha {opts.alpha:g}, delta {opts.delta:g} s, gamma {opts.gamma:g}, window {opts.window}, "
               f"end strategy {opts.end_strategy}")
    click.echo(f"p_m = {d['p_m']:.4g}, p_M = {d['p_M']:.4g}, {rates}, "
               f"min eig H = {d['h_min_eigenvalue']:.4g} at t = {d['h_min_eigenvalue_time_s']:.4g} s, "
               f"max ||K|| = {d['max_gain_norm']:.4g}")
    click.echo(f"wrote {out_dir / 'gains.npz'} and {out_dir / 'gains.json'}")
    return 0


def opts_record(value):
    """A stabilizer option for gains.json: numbers as floats, names as they are."""
    return value if isinstance(value, str) else float(value)


gains.help = gains.help.replace("{defaults}", DEFAULTS_HELP)
