"""Figures of one stabilized run: errors e(t), error inputs v(t), phase plot, gramian diagnostics."""

from __future__ import annotations

from . import subplots


def _title(ax, title: str | None):
    if title:
        ax.set_title(title, fontsize=9)


def errors_figure(t, e, state_names, title=None):
    """The paper's 'errors e versus time'."""
    fig, ax = subplots(figsize=(6.4, 3.6), layout="constrained")
    for j, name in enumerate(state_names):
        ax.plot(t, e[:, j], label=f"e_{name}")
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("e = x - x0")
    ax.legend(fontsize=8, ncol=len(state_names))
    _title(ax, title)
    return fig


def inputs_figure(t, v, input_names, title=None):
    """The paper's 'error inputs v versus time'."""
    fig, ax = subplots(figsize=(6.4, 3.6), layout="constrained")
    for j, name in enumerate(input_names):
        ax.plot(t, v[:, j], label=f"v_{name}")
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("v = u - u0")
    ax.legend(fontsize=8)
    _title(ax, title)
    return fig


def phase_figure(x_nominal, x_actual, labels=("x1", "x2"), title=None):
    """The paper's (x1, x2) phase plot of nominal and actual paths."""
    fig, ax = subplots(figsize=(5.0, 4.6), layout="constrained")
    ax.plot(x_nominal[:, 0], x_nominal[:, 1], color="k", lw=1.4, label="nominal")
    ax.plot(x_actual[:, 0], x_actual[:, 1], color="tab:red", lw=1.2, ls="--", label="actual")
    ax.plot(x_nominal[0, 0], x_nominal[0, 1], "ko", ms=4)
    ax.plot(x_actual[0, 0], x_actual[0, 1], "o", color="tab:red", ms=4)
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)
    _title(ax, title)
    return fig


def gramian_figure(t, h_min_eig, gain_norm, t_span=None, title=None):
    """Smallest eigenvalue of the window gramian H and the gain norm ||K|| along the schedule."""
    fig, ax = subplots(figsize=(6.4, 3.6), layout="constrained")
    ax.semilogy(t, h_min_eig, color="tab:blue", label="lambda_min(H)")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("lambda_min(H)", color="tab:blue")
    ax2 = ax.twinx()
    ax2.semilogy(t, gain_norm, color="tab:orange", label="||K||")
    ax2.set_ylabel("||K(t)||_2", color="tab:orange")
    if t_span is not None and t[-1] > t_span[1]:
        ax.axvspan(t_span[1], t[-1], color="0.9", zorder=0)
        ax.text(0.5 * (t_span[1] + t[-1]), 0.03, "beyond T:\nnot simulated", transform=ax.get_xaxis_transform(),
                ha="center", va="bottom", fontsize=7, color="0.35")
    _title(ax, title)
    return fig


def error_norm_comparison_figure(runs, title=None):
    """||e(t)|| of several runs on a log scale; ``runs`` is a list of (label, t, err_norm, status)."""
    fig, ax = subplots(figsize=(6.4, 3.8), layout="constrained")
    for label, t, en, status in runs:
        ax.semilogy(t, en, label=f"{label} ({status})")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("||e(t)||")
    ax.legend(fontsize=8)
    _title(ax, title)
    return fig
