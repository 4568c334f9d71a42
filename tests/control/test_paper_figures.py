"""The paper's figures: every axis carries its unit, states and inputs of different units lie on
separate panels (position and heading errors apart), every drawn line is in a legend, and legends lie
outside the axes they describe."""

from __future__ import annotations

import re

import pytest
from nhstab.paper import CASES, case_figures, run_case

#: per case: the error panels' and the input panels' y labels, the phase plot's axes, and the gramian's units
EXPECTED = {
    "hilare-circle": (
        {"position error [m]": {"e_x", "e_y"}, "heading error [rad]": {"e_theta"}},
        {"input error v [m/s]": {"v - nominal v"}, "input error omega [rad/s]": {"omega - nominal omega"}},
        ("x [m]", "y [m]"), ("[SI; m, rad mixed]", "[SI; (m/s, rad/s) per (m, rad)]")),
    "fwd-car-parking": (
        {"position error [m]": {"e_x", "e_y"}, "heading / steering angle error [rad]": {"e_theta", "e_phi"}},
        {"input error v [m/s]": {"v - nominal v"}, "input error omega_s [rad/s]": {"omega_s - nominal omega_s"}},
        ("x [m]", "y [m]"), ("[SI; m, rad mixed]", "[SI; (m/s, rad/s) per (m, rad)]")),
    "heisenberg-line": (
        {"error (dimensionless) [-]": {"e_x1", "e_x2", "e_x3"}},
        {"input error u1, u2 [1/s]": {"u1 - nominal u1", "u2 - nominal u2"}},
        ("x1 [-]", "x2 [-]"), ("[s]", "[1/s]")),
}


def _drawn_labels(ax) -> set[str]:
    return {ln.get_label() for ln in ax.get_lines() if not ln.get_label().startswith("_")}


def _legend_outside(fig, ax, legend) -> None:
    """The legend's box, after drawing, does not meet the axes' box (so it covers no data)."""
    fig.canvas.draw()
    lb, axb = legend.get_window_extent(), ax.get_window_extent()
    overlap_x = min(lb.x1, axb.x1) - max(lb.x0, axb.x0)
    overlap_y = min(lb.y1, axb.y1) - max(lb.y0, axb.y0)
    assert overlap_x <= 0.5 or overlap_y <= 0.5, (lb, axb)
    fb = fig.bbox
    assert fb.x0 - 1 <= lb.x0 and lb.x1 <= fb.x1 + 1 and fb.y0 - 1 <= lb.y0 and lb.y1 <= fb.y1 + 1, (lb, fb)


@pytest.fixture(scope="module", params=[pytest.param(n, marks=pytest.mark.slow) if n == "fwd-car-parking" else n
                                        for n in sorted(EXPECTED)])   # the FWD car's stiff loop: about 20 s
def figures(request):
    s = run_case(CASES[request.param], bound_checks=False)
    assert s["status"] == "converged", s["status"]
    return request.param, case_figures(s)


def test_error_and_input_panels_one_unit_each(figures):
    """One panel per unit: the hilare's and the car's position errors [m] apart from their heading
    (and steering) errors [rad], the Heisenberg states on one dimensionless panel; inputs likewise
    (m/s apart from rad/s; the Heisenberg inputs share 1/s). Each panel's lines are exactly its states,
    all in its legend, and the legend lies beside the axes."""
    name, figs = figures
    errors, inputs, _, _ = EXPECTED[name]
    for kind, expected in (("errors", errors), ("inputs", inputs)):
        fig = figs[kind]
        got = {ax.get_ylabel(): ax for ax in fig.axes}
        assert set(got) == set(expected), (kind, sorted(got))
        for label, ax in got.items():
            drawn = _drawn_labels(ax)
            assert expected[label] <= drawn and len(drawn - expected[label]) == 1, (label, drawn)   # + the zero line
            legend = ax.get_legend()
            assert {t.get_text() for t in legend.get_texts()} == drawn
            _legend_outside(fig, ax, legend)
        assert fig.axes[-1].get_xlabel() == "t [s]"


def test_phase_axes_carry_units(figures):
    """The phase plot's axes are the first two states with their units; nominal, actual and both
    starts are in the legend, beside the axes."""
    name, figs = figures
    fig = figs["phase"]
    (ax,) = fig.axes
    assert (ax.get_xlabel(), ax.get_ylabel()) == EXPECTED[name][2]
    legend = ax.get_legend()
    assert {t.get_text() for t in legend.get_texts()} == {"nominal", "actual", "nominal start", "actual start"}
    _legend_outside(fig, ax, legend)


def test_gramian_axes_carry_units(figures):
    """lambda_min(H) and ||K|| with units: s and 1/s for the Heisenberg system (one state unit, inputs
    per second); for the robots, whose states mix m and rad, labels naming the mix and a title saying
    that the values are those of the SI matrices. Both curves and the span beyond T are in the legend."""
    name, figs = figures
    fig = figs["gramian"]
    h_unit, k_unit = EXPECTED[name][3]
    ax, ax2 = fig.axes
    assert ax.get_ylabel() == f"lambda_min(H) {h_unit}" and ax2.get_ylabel() == f"||K(t)||_2 {k_unit}"
    assert ax.get_xlabel() == "t [s]"
    mixed = "mixed" in h_unit
    assert ("SI values" in fig.get_suptitle()) == mixed
    (legend,) = fig.legends
    texts = [t.get_text() for t in legend.get_texts()]
    assert texts == ["lambda_min(H) (left axis)", "||K(t)||_2 (right axis)", "beyond T: not simulated"]
    _legend_outside(fig, ax, legend)


def test_every_label_has_a_unit_in_brackets(figures):
    """Every axis of every figure of the case: a y label ending in a bracketed unit."""
    _, figs = figures
    for kind, fig in figs.items():
        for ax in fig.axes:
            assert re.search(r"\[[^\]]+\]$", ax.get_ylabel()), (kind, ax.get_ylabel())
            if ax.get_xlabel():
                assert re.search(r"\[[^\]]+\]$", ax.get_xlabel()), (kind, ax.get_xlabel())
