"""Figures of one stabilized run: errors e(t), error inputs v(t), phase plot, gramian diagnostics.

Every axis carries its unit. States and inputs of different units go on separate panels, one per
unit (position errors in m, heading and other angles in rad; inputs in m/s, rad/s), and states
without a unit (the Heisenberg system's) are marked dimensionless ``[-]``. Legends sit outside the
axes and list every drawn layer.
"""

from __future__ import annotations

from . import subplots

#: the quantity a state of each unit is, on the error panels
UNIT_NAMES = {"m": "position error", "rad": "heading / angle error", "": "error (dimensionless)"}


def unit_groups(names, units) -> list[tuple[str, list[int]]]:
    """Indices of ``names`` grouped by unit, in first-appearance order: [(unit, [i, ...]), ...]; a
    name without a unit in ``units`` counts as dimensionless ('')."""
    groups: dict = {}
    for i, _ in enumerate(names):
        groups.setdefault(units[i] if i < len(units) else "", []).append(i)
    return list(groups.items())


def with_unit(text: str, unit: str) -> str:
    """``text [unit]``, with ``[-]`` for a dimensionless quantity."""
    return f"{text} [{unit or '-'}]"


def error_axis_label(names, unit: str) -> str:
    """The label of an error panel holding the states ``names`` of one ``unit``."""
    names = list(names)
    if names == ["theta"]:
        return with_unit("heading error", unit)
    if sorted(names) == ["phi", "theta"]:
        return with_unit("heading / steering angle error", unit)
    what = UNIT_NAMES.get(unit, "error")
    return with_unit(what, unit)


def norm_label(units, what: str = "||e(t)||") -> str:
    """The label of the Euclidean norm of a vector whose entries have ``units``: its unit when they
    share one, else the units it mixes (the norm of the SI values)."""
    distinct = list(dict.fromkeys(u or "-" for u in units))
    if len(distinct) == 1:
        return f"{what} [{distinct[0]}]"
    return f"{what} [{', '.join(distinct)} mixed]"


def _title(fig, title: str | None):
    if title:
        fig.suptitle(title, fontsize=9)


def _legend_beside(ax):
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)


def _unit_panels(t, values, names, units, line_label, axis_label, zero_label, title):
    """One panel per unit of ``names`` (values (T, len(names)) against t), each line labelled
    ``line_label(name)``, the panel's axis ``axis_label(names on it, unit)``, a zero line, the legend beside."""
    groups = unit_groups(names, units)
    fig, axes = subplots(len(groups), 1, figsize=(7.4, 1.9 * len(groups) + 1.0), sharex=True, layout="constrained",
                         squeeze=False)
    axes = axes[:, 0]
    for ax, (unit, idx) in zip(axes, groups):
        for i in idx:
            ax.plot(t, values[:, i], lw=1.1, label=line_label(names[i]))
        ax.axhline(0.0, color="0.6", lw=0.6, label=zero_label)
        ax.set_ylabel(axis_label([names[i] for i in idx], unit))
        ax.grid(alpha=0.3)
        _legend_beside(ax)
    axes[-1].set_xlabel("t [s]")
    _title(fig, title)
    return fig


def errors_figure(t, e, state_names, state_units=(), title=None):
    """The paper's 'errors e versus time', one panel per unit of the states."""
    return _unit_panels(t, e, state_names, state_units, lambda s: f"e_{s}", error_axis_label, "zero error", title)


def inputs_figure(t, v, input_names, input_units=(), title=None):
    """The paper's 'error inputs v = u - u0 versus time', one panel per unit of the inputs."""
    return _unit_panels(t, v, input_names, input_units, lambda s: f"{s} - nominal {s}",
                        lambda on, unit: with_unit("input error " + ", ".join(on), unit), "zero", title)


def phase_figure(x_nominal, x_actual, labels=("x1", "x2"), units=("", ""), title=None):
    """The paper's (x1, x2) phase plot of nominal and actual paths, with their starts."""
    fig, ax = subplots(figsize=(6.6, 4.8), layout="constrained")
    ax.plot(x_nominal[:, 0], x_nominal[:, 1], color="k", lw=1.4, label="nominal")
    ax.plot(x_actual[:, 0], x_actual[:, 1], color="tab:red", lw=1.2, ls="--", label="actual")
    ax.plot(x_nominal[0, 0], x_nominal[0, 1], "ko", ms=4, ls="none", label="nominal start")
    ax.plot(x_actual[0, 0], x_actual[0, 1], "o", color="tab:red", ms=4, ls="none", label="actual start")
    units = tuple(units) + ("",) * (2 - len(units))
    ax.set_xlabel(with_unit(labels[0], units[0]))
    ax.set_ylabel(with_unit(labels[1], units[1]))
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    _legend_beside(ax)
    _title(fig, title)
    return fig


def gramian_units(state_units, input_units) -> tuple[str, str, str | None]:
    """Units of lambda_min(H) and of ||K||, and a note when H and K mix units.

    H = int Phi B B^T Phi^T w dtau with a unit input weight: when every state has one unit U and every
    input is U per second, B is dimensionless, H is in s and K = gamma B^T P (v = -K e) in 1/s.
    Otherwise H and K have entries of different units and their eigenvalue and norm are those of the
    matrices of SI values; the labels say which units they mix."""
    su = list(dict.fromkeys(u for u in state_units))
    iu = list(dict.fromkeys(u for u in input_units))
    if len(su) == 1 and len(iu) == 1 and iu[0] in (f"{su[0]}/s", "1/s" if not su[0] else None):
        return "s", "1/s", None
    states = ", ".join(u or "-" for u in su)
    inputs = ", ".join(iu)
    return (f"SI; {states} mixed", f"SI; ({inputs}) per ({states})",
            f"H and K mix units (states in {states}, inputs in {inputs}): eigenvalue and norm of their SI values")


def gramian_figure(t, h_min_eig, gain_norm, t_span=None, title=None, state_units=(), input_units=()):
    """Smallest eigenvalue of the window gramian H and the gain norm ||K|| along the schedule."""
    h_unit, k_unit, note = gramian_units(state_units, input_units)
    fig, ax = subplots(figsize=(7.4, 4.2), layout="constrained")
    h_line, = ax.semilogy(t, h_min_eig, color="tab:blue", label="lambda_min(H) (left axis)")
    ax.set_xlabel("t [s]")
    ax.set_ylabel(f"lambda_min(H) [{h_unit}]", color="tab:blue")
    ax2 = ax.twinx()
    k_line, = ax2.semilogy(t, gain_norm, color="tab:orange", label="||K(t)||_2 (right axis)")
    ax2.set_ylabel(f"||K(t)||_2 [{k_unit}]", color="tab:orange")
    handles = [h_line, k_line]
    if t_span is not None and t[-1] > t_span[1]:
        handles.append(ax.axvspan(t_span[1], t[-1], color="0.9", zorder=0, label="beyond T: not simulated"))
    ax.grid(alpha=0.3)
    fig.legend(handles=handles, fontsize=7, loc="outside lower center", ncol=len(handles))
    if note:
        title = f"{title}\n{note}" if title else note
    _title(fig, title)
    return fig


def error_norm_comparison_figure(runs, title=None, units=()):
    """||e(t)|| of several runs on a log scale; ``runs`` is a list of (label, t, err_norm, status) and
    ``units`` the units of the states whose errors the norm takes."""
    fig, ax = subplots(figsize=(7.6, 3.8), layout="constrained")
    for label, t, en, status in runs:
        ax.semilogy(t, en, label=f"{label} ({status})")
    ax.set_xlabel("t [s]")
    ax.set_ylabel(norm_label(units))
    ax.grid(alpha=0.3)
    _legend_beside(ax)
    _title(fig, title)
    return fig
