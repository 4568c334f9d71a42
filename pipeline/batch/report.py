"""The batch report (``nhstab batch report STORE``): HTML with PNG figures, a Markdown twin, and a
CSV of every trial. Every number in it is read from the store (trials.sqlite), nothing else.

Rates come with Wilson score 95% intervals. The tracking-error envelopes are percentiles over the
trials of ||e(t)|| while each trial follows its first plan, with the guaranteed bound of the noiseless
linearised loop drawn from each trial's own plan and true initial error (median over trials): for the
future window Proposition 1's 3 alpha bound sqrt(e0^T P(0) e0 / lambda_min(P(t))) exp(-3 alpha t)
(docs/theory/control-law.md, The guarantee), for the frozen-time law its certified bound; none for the
past window. Stores written before the trials recorded that curve (their metrics have ``rate_bound`` =
the printed 2 alpha p_m / p_M and no ``rate_bound_printed``) get the 3 alpha bound with its uniform
constant, ||e(0)|| sqrt(p_M / p_m) exp(-3 alpha t), alpha recovered as rate_bound p_M / (2 p_m).

The error tubes (:mod:`nhstab.tubes`) held to reality: per cell, the coverage of each trial's first
plan's p-tube, the fraction of its tracking samples inside it (the pose region the spatial tube is
built from, and the full-state p-ellipsoid), with a Wilson 95% interval over samples (samples of one
trial are correlated, so that interval is too narrow; the spread of the per-trial fractions is given
beside it), and per state the observed RMS error over trials against the predicted one,
sqrt(mean over trials of sigma^2 + m^2) of each trial's own tube, against time.
"""

from __future__ import annotations

import csv
import html
import io
import math
from pathlib import Path

import numpy as np
from scipy.stats import binomtest as _binomtest
from scipy.stats import norm as _norm

from ..errors import InputError
from ..records import OutputFolder
from ..report import subplots
from .store import Store

Z95 = 1.959963984540054


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float, float, float]:
    """The Wilson score interval for a binomial proportion.

    Parameters
    ----------
    successes : int
        Number of successes, 0 to ``n``.
    n : int
        Number of trials; 0 gives NaNs.
    z : float
        Standard normal quantile of the two-sided level (default: 95 %).

    Returns
    -------
    tuple of float
        ``(rate, low, high)``, from :func:`scipy.stats.binomtest`'s ``proportion_ci(method="wilson")``,
        with the ends made to bracket the rate exactly (rounding can leave an end a few ulp on the
        wrong side of it at 0 or n successes, and matplotlib refuses such error bars).
    """
    if n == 0:
        return math.nan, math.nan, math.nan
    p = successes / n
    level = 2.0 * float(_norm.cdf(z)) - 1.0
    ci = _binomtest(int(successes), int(n)).proportion_ci(confidence_level=level, method="wilson")
    return p, min(p, max(0.0, float(ci.low))), max(p, min(1.0, float(ci.high)))


def _cells(trials: list[dict]) -> dict:
    cells: dict = {}
    for t in trials:
        cells.setdefault(t["cell"], []).append(t)
    return cells


def _m(t, key):
    return (t.get("metrics") or {}).get(key)


def bound_metrics(metrics: dict | None) -> dict:
    """rate_bound (the guaranteed 3 alpha) and rate_bound_printed (the paper's 2 alpha p_m / p_M) of a
    trial's metrics, for stores of either generation: before the 3 alpha bound, ``rate_bound`` held
    the printed value (and ``rate_bound_printed`` was absent); the gramian law then always used the
    future window with weight 6, so its 3 alpha is rate_bound p_M / p_m * 3 / 2."""
    m = metrics or {}
    if "rate_bound_printed" in m or m.get("rate_bound") is None or not m.get("p_m"):
        return {"rate_bound": m.get("rate_bound"), "rate_bound_printed": m.get("rate_bound_printed")}
    alpha = m["rate_bound"] * m["p_M"] / (2.0 * m["p_m"])
    return {"rate_bound": 3.0 * alpha, "rate_bound_printed": m["rate_bound"]}


def cell_table(trials: list[dict]) -> list[dict]:
    rows = []
    for cell, ts in _cells(trials).items():
        spec = ts[0]["spec"]["cell_spec"]
        n = len(ts)
        done = [t for t in ts if t["status"] != "error"]
        row = {"cell": cell, "map": spec["map"], "robot": _m(ts[0], "robot") or spec["robot"],
               "controller": spec["controller"], "window": spec.get("window"), "alpha": spec["alpha"],
               "delta": spec["delta"],
               "gamma": spec["gamma"], "noise": spec["noise"], "trials": n, "errors": n - len(done)}
        for key, pred in (("success", lambda t: t["status"] == "reached"),
                          ("collision", lambda t: t["status"] == "collision"),
                          ("margin_violation", lambda t: bool(_m(t, "margin_violation")))):
            k = sum(1 for t in done if pred(t))
            rate, lo, hi = wilson(k, len(done))
            row.update({f"{key}_count": k, f"{key}_rate": rate, f"{key}_lo": lo, f"{key}_hi": hi})
        for key in ("min_clearance_m", "final_position_error_m", "replans", "max_error_norm", "margin_m"):
            vals = [_m(t, key) for t in done if _m(t, key) is not None]
            row[f"{key}_median"] = float(np.median(vals)) if vals else math.nan
        if any(_m(t, "jackknife") is not None for t in done):     # a car with trailers
            k = sum(1 for t in done if _m(t, "jackknife"))
            rate, lo, hi = wilson(k, len(done))
            row.update({"jackknife_count": k, "jackknife_rate": rate, "jackknife_lo": lo, "jackknife_hi": hi})
            for key in ("max_abs_hitch_angle_rad", "final_trailer_position_error_m"):
                vals = [_m(t, key) for t in done if _m(t, key) is not None and _m(t, key) == _m(t, key)]
                row[f"{key}_median"] = float(np.median(vals)) if vals else math.nan
        _tube_cells(row, done)
        lat = [x for t in done for x in (t.get("timings") or {}).get("replan_latencies_s", [])]
        row["replan_latency_median_s"] = float(np.median(lat)) if lat else math.nan
        row["replan_latency_p95_s"] = float(np.percentile(lat, 95)) if lat else math.nan
        rows.append(row)
    return rows


def _tube_cells(row: dict, done: list[dict]) -> None:
    """Coverage of the trials' first-plan tubes: pooled over samples (Wilson 95%) and per trial."""
    with_tube = [t for t in done if _m(t, "tube_samples")]
    n = sum(int(_m(t, "tube_samples")) for t in with_tube)
    row["tube_samples"] = n
    row["tube_probability"] = _m(with_tube[0], "tube_probability") if with_tube else None
    for key in ("inside", "inside_state"):
        k = sum(int(round(_m(t, "tube_samples") * _m(t, f"tube_{key}"))) for t in with_tube)
        rate, lo, hi = wilson(k, n)
        per = np.array([_m(t, f"tube_{key}") for t in with_tube], dtype=float)
        row.update({f"tube_{key}_rate": rate, f"tube_{key}_lo": lo, f"tube_{key}_hi": hi,
                    f"tube_{key}_trial_sd": float(per.std(ddof=1)) if len(per) > 1 else math.nan,
                    f"tube_{key}_min_trial": float(per.min()) if len(per) else math.nan})
    cert = [c for c in (_m(t, "tube_certified_clearance_m") for t in with_tube) if c is not None]
    sat = [_m(t, "tube_saturation_probability") for t in with_tube]
    row["tube_certified_clearance_median_m"] = float(np.median(cert)) if cert else math.nan
    row["tube_saturation_median"] = float(np.median(sat)) if sat else math.nan


def trials_csv(trials: list[dict]) -> str:
    keys = ["status", "reached", "collision", "margin_violation", "min_clearance_m", "margin_m",
            "final_position_error_m", "final_heading_error_rad", "replans", "discovered", "rms_error_norm",
            "max_error_norm", "rms_position_error_m", "max_position_error_m", "duration_s", "e0_norm", "p_m", "p_M",
            "rate_bound", "rate_bound_printed", "tube_certified_clearance_m", "tube_saturation_probability",
            "tube_max_position_radius_m", "tube_samples", "tube_inside", "tube_inside_state",
            "jackknife", "max_abs_hitch_angle_rad", "final_trailer_position_error_m",
            "final_trailer_heading_error_rad"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["id", "cell", "trial", "seed", "map", "robot", "controller", "window", "alpha", "delta", "gamma",
                "noise", *keys, "replan_latencies_s", "error"])
    for t in trials:
        c = t["spec"]["cell_spec"]
        m = {**(t.get("metrics") or {})}
        if t.get("metrics"):
            m.update(bound_metrics(m))
        window = c.get("window") or m.get("window") or ("future" if c["controller"] == "gramian" else "")
        w.writerow([t["id"], t["cell"], t["trial"], t["seed"], c["map"], m.get("robot") or c["robot"],
                    c["controller"], window, c["alpha"], c["delta"], c["gamma"], c["noise"], t["status"],
                    *[("" if m.get(k) is None else _num(m[k])) for k in keys[1:]],
                    ";".join(f"{x:.4f}" for x in (t.get("timings") or {}).get("replan_latencies_s", [])),
                    t.get("error") or ""])
    return buf.getvalue()


def _num(v):
    if isinstance(v, bool):
        return int(v)
    return repr(float(v)) if isinstance(v, float) else v


def _label(row) -> str:
    gains = "".join(f" {name}{row[key]:g}" for name, key in (("a", "alpha"), ("d", "delta"), ("g", "gamma"))
                    if row[key] is not None)
    ctrl = row["controller"] + (f" {row['window']}" if row.get("window") else "")
    return f"{row['map']} / {ctrl}{gains} / noise {row['noise']:g}"


# ---- figures ---------------------------------------------------------------------------------------

def _state_unit(name: str) -> str:
    """The unit of a built-in model's state (every model that has the name gives it this unit): x, y in
    m; theta, theta_i (a trailer's heading) and phi (a steering angle) in rad; else none (heisenberg)."""
    if name in ("x", "y"):
        return "m"
    return "rad" if name == "phi" or name.startswith("theta") else ""


def _legend_outside(ax, fontsize: float, handles_labels=None) -> None:
    """The legend to the right of the axes, outside them (the constrained layout makes room): never over
    a curve or a marker."""
    handles, labels = handles_labels if handles_labels is not None else ax.get_legend_handles_labels()
    if handles:
        ax.legend(handles, labels, fontsize=fontsize, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)


def rates_figure(rows):
    fig, ax = subplots(figsize=(9, 0.45 * len(rows) + 1.6), layout="constrained")
    y = np.arange(len(rows))
    for j, (key, color) in enumerate((("success", "tab:green"), ("collision", "tab:red"),
                                      ("margin_violation", "tab:orange"))):
        rate = np.array([r[f"{key}_rate"] for r in rows])
        err = np.clip(np.array([[r[f"{key}_rate"] - r[f"{key}_lo"] for r in rows],
                                [r[f"{key}_hi"] - r[f"{key}_rate"] for r in rows]]), 0.0, None)
        ax.errorbar(rate, y + (j - 1) * 0.22, xerr=err, fmt="o", color=color, capsize=3,
                    label=key.replace("_", " ") + " (Wilson 95%)")
    ax.set_yticks(y, [_label(r) for r in rows], fontsize=7)
    ax.set_xlim(-0.02, 1.02)
    ax.set_xlabel("rate over trials")
    ax.invert_yaxis()
    ax.grid(alpha=0.3)
    _legend_outside(ax, 7)
    ax.set_title("Success, collision and margin-violation rates per cell", fontsize=9)
    return fig


#: the per-cell time-series figures (envelopes, tubes: a row of panels per cell) draw at most this many
#: cells, so that a large batch's report stays readable and small; the tables and trials.csv have them all
FIGURE_CELLS_MAX = 12


def figure_rows(rows: list[dict]) -> tuple[list[dict], str]:
    """The cells the per-cell time-series figures draw, and the note their captions carry: every cell
    up to FIGURE_CELLS_MAX; beyond it the cells at the default noise level (1) in table order, cut at
    FIGURE_CELLS_MAX (or the first cells, if no cell is at noise 1)."""
    if len(rows) <= FIGURE_CELLS_MAX:
        return rows, ""
    default = [r for r in rows if r.get("noise") == 1.0]
    pool, which = (default, "the cells at noise 1, in table order") if default else (rows, "in table order")
    shown = pool[:FIGURE_CELLS_MAX]
    return shown, (f" Drawn: {len(shown)} of the {len(rows)} cells ({which}; at most {FIGURE_CELLS_MAX}); "
                   "the tables and trials.csv hold every cell.")


#: percentiles over trials are drawn from this many trials on; fewer are drawn one curve per trial
PERCENTILE_TRIALS = 3


def _kept(count: np.ndarray, n: int) -> np.ndarray:
    """The time samples a curve over ``n`` trials is drawn at: where at least half of them, and at least
    PERCENTILE_TRIALS (all of them, when fewer trials ran), still follow their first plan."""
    return count >= max(min(PERCENTILE_TRIALS, n), 0.5 * n)


def envelope_figure(trials, rows):
    """Per gramian cell (and the baselines beside them): percentiles of ||e(t)|| over trials (each trial's
    own curve in a cell of fewer than PERCENTILE_TRIALS trials), and the median over trials of each
    trial's own gramian bound. None when no trial recorded its error series."""
    cells = _cells(trials)
    rows = [r for r in rows if any(t.get("series") for t in cells[r["cell"]])]
    if not rows:
        return None
    fig, axes = subplots(len(rows), 1, figsize=(8, 2.2 * len(rows) + 0.6), sharex=True, squeeze=False,
                             layout="constrained")
    for ax, row in zip(axes[:, 0], rows):
        series = [t["series"] for t in cells[row["cell"]] if t.get("series")]
        dt = series[0]["dt_s"]
        length = max(len(s["error_norm"]) for s in series)
        E = np.full((len(series), length), np.nan)
        for i, s in enumerate(series):
            E[i, :len(s["error_norm"])] = s["error_norm"]
        t = dt * np.arange(length)
        count = np.sum(np.isfinite(E), axis=0)
        keep = _kept(count, len(series))
        if len(series) >= PERCENTILE_TRIALS:
            for q, style in ((50, "-"), (90, "--"), (99, ":")):
                ax.semilogy(t[keep], np.nanpercentile(E[:, keep], q, axis=0), "k" + style, lw=1.0,
                            label=f"{q}th percentile")
        else:                                   # too few trials for percentiles: each trial's own curve
            for i, e in enumerate(E):
                ax.semilogy(t, e, color="k", lw=0.9, ls=("-", "--")[i % 2], label=f"trial {i + 1}")
        bounds = [b for b in (_bound_curve(tr, t) for tr in cells[row["cell"]]) if b is not None]
        if bounds:
            B = np.array(bounds)
            ok = keep & (np.sum(np.isfinite(B), axis=0) >= max(1, 0.5 * len(bounds)))
            label = ("3 alpha bound" if row.get("window") in (None, "future") else "certified bound") + \
                " (noiseless linearised loop; median over trials)"
            ax.semilogy(t[ok], np.nanmedian(B[:, ok], axis=0), color="tab:blue", lw=1.0, label=label)
        ax.set_ylabel("||e|| [-]")
        few = "" if len(series) >= PERCENTILE_TRIALS else f"; fewer than {PERCENTILE_TRIALS}: each trial drawn"
        ax.set_title(_label(row) + f"  ({len(series)} trial{'s' if len(series) != 1 else ''}{few})", fontsize=8)
        ax.grid(alpha=0.3)
        _legend_outside(ax, 6)
    axes[-1, 0].set_xlabel("t [s] (while following the first plan)")
    return fig


def tube_figure(trials, rows):
    """Per cell (rows) and state (columns): the observed RMS tracking error over trials against the
    predicted sqrt(mean over trials of sigma^2 + m^2), from each trial's own first-plan tube, against
    time (while the trials follow their first plan)."""
    cells = _cells(trials)
    shown = [r for r in rows if any((t.get("series") or {}).get("tube_std") for t in cells[r["cell"]])]
    if not shown:
        return None
    width = max(len(t["series"]["state_names"]) for r in shown for t in cells[r["cell"]]
                if (t.get("series") or {}).get("tube_std"))
    fig, axes = subplots(len(shown), width, figsize=(3.2 * width, 2.0 * len(shown) + 0.6), squeeze=False,
                         sharex="row", layout="constrained")
    for i, row in enumerate(shown):
        series = [t["series"] for t in cells[row["cell"]] if (t.get("series") or {}).get("tube_std")]
        names = series[0]["state_names"]
        dt = series[0]["dt_s"]
        length = max(len(s["tube_std"]) for s in series)
        n = len(names)
        E, P = np.full((len(series), length, n), np.nan), np.full((len(series), length, n), np.nan)
        for j, s in enumerate(series):
            k = len(s["tube_std"])
            E[j, :k] = np.asarray(s["error_by_state"])[:k]
            P[j, :k] = np.asarray(s["tube_std"]) ** 2 + np.asarray(s["tube_mean"]) ** 2
        for c in range(n, width):
            axes[i, c].set_visible(False)
        count = np.sum(np.isfinite(E[:, :, 0]), axis=0)
        keep = _kept(count, len(series))
        t = dt * np.arange(length)
        for c, name in enumerate(names):
            ax = axes[i, c]
            ax.plot(t[keep], np.sqrt(np.nanmean(E[:, keep, c] ** 2, axis=0)), color="k", lw=1.0, label="observed RMS")
            ax.plot(t[keep], np.sqrt(np.nanmean(P[:, keep, c], axis=0)), color="tab:blue", lw=1.0, ls="--",
                    label="predicted RMS (tube)")
            unit = _state_unit(name)
            ax.set_title((_label(row) + f" ({len(series)} trial{'s' if len(series) != 1 else ''})\n" if c == 0 else "\n")
                         + f"e_{name}", fontsize=7, loc="left")
            ax.set_ylabel(f"RMS e_{name}" + (f" [{unit}]" if unit else " [-]"), fontsize=7)
            ax.grid(alpha=0.3)
        _legend_outside(axes[i, n - 1], 6, axes[i, 0].get_legend_handles_labels())   # right of the row
    for ax in axes[-1]:
        ax.set_xlabel("t [s] (first plan)")
    return fig
def _bound_curve(trial: dict, t: np.ndarray):
    """The trial's guaranteed bound at times t (NaN past its series), or None (no gramian bound)."""
    series = trial.get("series") or {}
    m = trial.get("metrics") or {}
    if series.get("bound") is not None:
        out = np.full(len(t), np.nan)
        b = np.asarray(series["bound"], dtype=float)
        out[:min(len(b), len(t))] = b[:len(t)]
        return out
    spec = trial["spec"]["cell_spec"]
    run_window = ((trial["spec"].get("run") or {}).get("controller") or {}).get("window")
    if spec["controller"] != "gramian" or spec.get("window") not in (None, "future") or \
            run_window not in (None, "future") or "rate_bound_printed" in m:
        return None
    if not m.get("p_m") or m.get("e0_norm") is None or m.get("rate_bound") is None:
        return None
    # an older store: the 3 alpha bound with its uniform constant sqrt(p_M / p_m)
    rate = bound_metrics(m)["rate_bound"]
    return m["e0_norm"] * math.sqrt(m["p_M"] / m["p_m"]) * np.exp(-rate * t)


def distributions_figure(trials, rows):
    cells = _cells(trials)
    keys = [("min_clearance_m", "min executed clearance [m]"), ("final_position_error_m", "final position error [m]"),
            ("replans", "replans"), ("replan_latency", "replan latency [s]")]
    fig, axes = subplots(1, 4, figsize=(13, 0.4 * len(rows) + 2.0), sharey=True, layout="constrained")
    for ax, (key, title) in zip(axes, keys):
        data = []
        for row in rows:
            ts = [t for t in cells[row["cell"]] if t["status"] != "error"]
            if key == "replan_latency":
                vals = [x for t in ts for x in (t.get("timings") or {}).get("replan_latencies_s", [])]
            else:
                vals = [_m(t, key) for t in ts if _m(t, key) is not None]
            data.append(vals if vals else [np.nan])
        ax.boxplot(data, orientation="horizontal", widths=0.6, showfliers=True, flierprops={"markersize": 3})
        if key == "min_clearance_m":
            margins = sorted({_m(t, "margin_m") for t in trials if _m(t, "margin_m") is not None})
            for i, mg in enumerate(margins):
                ax.axvline(mg, color="tab:orange", ls="--", lw=0.8,
                           label=None if i else "planning margin" + ("s (per map)" if len(margins) > 1 else ""))
            ax.axvline(0.0, color="tab:red", lw=0.8, label="contact (clearance 0)")
        ax.set_title(title, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_yticks(np.arange(1, len(rows) + 1), [_label(r) for r in rows], fontsize=7)
    axes[0].invert_yaxis()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles, labels = axes[0].get_legend_handles_labels()
    handles += [Patch(facecolor="none", edgecolor="k"), Line2D([], [], color="tab:orange"),
                Line2D([], [], color="k", marker="o", ls="none", markersize=3, markerfacecolor="none")]
    labels += ["trials' middle half (quartiles)", "median", "beyond 1.5 x the box (whiskers end there)"]
    _legend_outside(axes[-1], 6, (handles, labels))
    return fig


def paired_figure(trials):
    """Controllers on the same seeds: each trial's minimum clearance under the gramian law against a
    baseline's, for every (map, noise) cell group where both ran."""
    by = {}
    for t in trials:
        c = t["spec"]["cell_spec"]
        if t["status"] == "error":
            continue
        by.setdefault((c["map"], c["problem"], c["noise"]), {}).setdefault(_controller_name(c), {})[t["trial"]] = \
            _m(t, "min_clearance_m")
    # the reference: the paper's law (the future window, or the one gramian cell of an older store)
    ref = "gramian future" if any("gramian future" in v for v in by.values()) else "gramian"
    pairs = [(k, v) for k, v in by.items() if ref in v and len(v) > 1]
    if not pairs:
        return None
    fig, ax = subplots(figsize=(5.5, 5), layout="constrained")
    markers = {"open-loop": "x", "tvlqr": "o", "gramian past": "v", "gramian frozen-time": "^"}
    lo, hi = np.inf, -np.inf
    many = len(pairs) > 6              # a legend entry per map and noise would bury the axes: one per controller
    labelled = set()
    for (mp, _, noise), ctrls in pairs:
        for base, vals in ctrls.items():
            if base == ref:
                continue
            ks = sorted(set(vals) & set(ctrls[ref]))
            xs = np.array([vals[k] for k in ks], float)
            ys = np.array([ctrls[ref][k] for k in ks], float)
            label = (None if base in labelled else base) if many else f"{base}, {mp}, noise {noise:g}"
            labelled.add(base)
            ax.scatter(xs, ys, marker=markers.get(base, "s"), s=18, label=label)
            both = np.concatenate([xs, ys])
            both = both[np.isfinite(both)]
            if len(both):
                lo, hi = min(lo, float(both.min())), max(hi, float(both.max()))
    if np.isfinite(lo):
        ax.plot([lo, hi], [lo, hi], color="0.5", lw=0.8)
    ax.set_xlabel("baseline: min executed clearance [m]")
    ax.set_ylabel(f"{ref}: min executed clearance [m] (same seed)")
    ax.grid(alpha=0.3)
    _legend_outside(ax, 6)
    ax.set_title(f"Same seeds, two controllers\n(above the diagonal: {ref} kept more room)", fontsize=8)
    return fig


def paired_outcomes(trials: list[dict]) -> list[dict]:
    """Controllers on the same seeds, against the reference (the gramian law's future window): per
    (map, problem, noise) and controller, on how many of the seeds where the reference reached the goal
    this controller reached it too (without a collision, which ends a run), and where it collided."""
    by: dict = {}
    for t in trials:
        if t["status"] == "error":
            continue
        c = t["spec"]["cell_spec"]
        by.setdefault((c["map"], c["problem"], c["noise"]), {}).setdefault(_controller_name(c), {})[t["trial"]] = \
            t["status"]
    ref = "gramian future" if any("gramian future" in v for v in by.values()) else "gramian"
    rows = []
    for (mp, problem, noise), ctrls in by.items():
        if ref not in ctrls:
            continue
        base = {k for k, st in ctrls[ref].items() if st == "reached"}
        for name, sts in sorted(ctrls.items()):
            if name == ref:
                continue
            common = base & set(sts)
            k = sum(1 for s in common if sts[s] == "reached")
            rows.append({"map": mp, "problem": problem, "noise": noise, "reference": ref, "controller": name,
                         "reference_reached": len(common), "also_reached": k,
                         "fraction": k / len(common) if common else math.nan,
                         "collisions": sum(1 for st in sts.values() if st == "collision"), "trials": len(sts)})
    return rows


def _controller_name(cell: dict) -> str:
    return cell["controller"] + (f" {cell['window']}" if cell.get("window") else "")


def noise_figure(rows):
    groups = {}
    for r in rows:
        key = (r["map"], _controller_name(r), r["alpha"], r["delta"], r["gamma"])
        groups.setdefault(key, []).append(r)
    groups = {k: v for k, v in groups.items() if len({r["noise"] for r in v}) > 1}
    if not groups:
        return None
    fig, ax = subplots(figsize=(6.5, 4.2), layout="constrained")
    for (mp, ctrl, a, d, g), rs in groups.items():
        rs = sorted(rs, key=lambda r: r["noise"])
        x = [r["noise"] for r in rs]
        y = [r["success_rate"] for r in rs]
        err = np.clip([[r["success_rate"] - r["success_lo"] for r in rs],
                       [r["success_hi"] - r["success_rate"] for r in rs]], 0.0, None)
        gains = "".join(f" {name}{v:g}" for name, v in (("a", a), ("d", d), ("g", g)) if v is not None)
        ax.errorbar(x, y, yerr=err, marker="o", capsize=3, label=f"{ctrl}{gains} ({mp})")
    ax.set_xlabel("noise level (scale of every noise source)")
    ax.set_ylabel("success rate (Wilson 95%)")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    _legend_outside(ax, 7)
    return fig


# ---- the report ----------------------------------------------------------------------------------------

def _fmt_rate(r, key):
    if not r[f"{key}_rate"] == r[f"{key}_rate"]:
        return "-"
    return f"{100 * r[key + '_rate']:.0f}% [{100 * r[key + '_lo']:.0f}, {100 * r[key + '_hi']:.0f}]"


TUBE_HEADER = ["cell", "samples", "inside tube [Wilson 95%]", "per-trial sd / min", "inside state ellipsoid",
               "median certified clearance [m]", "median saturation bound"]


def _tube_row(r) -> list[str]:
    def cov(key):
        return (f"{100 * r[f'tube_{key}_rate']:.2f}% [{100 * r[f'tube_{key}_lo']:.2f}, "
                f"{100 * r[f'tube_{key}_hi']:.2f}]")

    return [_label(r), str(r["tube_samples"]), cov("inside"),
            f"{100 * r['tube_inside_trial_sd']:.2f} / {100 * r['tube_inside_min_trial']:.1f}%", cov("inside_state"),
            _fmt(r["tube_certified_clearance_median_m"]), _fmt(r["tube_saturation_median"])]


def _fmt(v, digits=3):
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}g}"


TRAILER_NOTE = ("Cars with trailers: a jackknife (a hitch angle beyond the jackknife limit) ends a trial as a "
                "collision of the rig with itself and is counted in the collision rate above too; the hitch angle "
                "is the largest |theta_(i-1) - theta_i| of the trial, the final error the last trailer's axle's.")


def _trailer_table(rows):
    """The trailer columns of the cells whose trials carry them (header, rows)."""
    header = ["cell", "jackknife", "median max hitch angle [rad]", "median final trailer error [m]"]
    return header, [[_label(r), _fmt_rate(r, "jackknife"), _fmt(r["max_abs_hitch_angle_rad_median"]),
                     _fmt(r["final_trailer_position_error_m_median"])] for r in rows if "jackknife_rate" in r]


def write_report(store_path, out_dir=None) -> list[Path]:
    """Write report.html, report.md, trials.csv and figures/*.png next to the store (or in out_dir)."""
    store_path = Path(store_path)
    db = store_path / "trials.sqlite" if store_path.is_dir() else store_path
    out_dir = Path(out_dir) if out_dir is not None else db.parent
    with Store(db) as store:            # read-only; refused unless it is a batch store
        trials = store.trials()
        config = store.meta("config", {})
        vers = store.meta("versions", {})
        runs = store.meta("runs", [])
    if not trials:
        raise InputError("STORE", "a batch store with at least one finished trial", str(db),
                         detail="no trial is stored yet")
    if not isinstance(config, dict) or not isinstance(vers, dict):
        raise InputError("STORE", "a batch store whose config and versions are mappings", str(db))
    rows = cell_table(trials)
    drawn, _ = figure_rows(rows)
    figs = {"rates": rates_figure(rows), "envelopes": envelope_figure(trials, drawn),
            "distributions": distributions_figure(trials, rows), "tubes": tube_figure(trials, drawn),
            "paired": paired_figure(trials),
            "noise": noise_figure(rows)}
    owned = REPORT_FILES + tuple(f"figures/{name}.png" for name in figs)     # those not drawn this time too
    with OutputFolder(out_dir, "batch report", owned=owned, info={"store": str(db), "trials": len(trials)}) as out:
        _write_report(out, db, trials, config, vers, rows, figs, runs)
    return out.written


def left_out(trials: list[dict], rows: list[dict], figs: dict) -> dict:
    """Why each figure that is not drawn (None in ``figs``) is left out: one line per figure."""
    levels = ", ".join(sorted({f"{r['noise']:g}" for r in rows}))
    why = {
        "envelopes": "no trial recorded its tracking-error series (every trial ended before it followed a plan)",
        "tubes": "no trial's first plan has a recorded error tube to compare with",
        "paired": "no map and noise level ran the reference controller (the gramian law) and another one on the "
                  "same seeds",
        "noise": f"no cell group ran at more than one noise level (levels: {levels})",
    }
    return {name: why.get(name, "nothing to draw") for name, fig in figs.items() if fig is None}


ERROR_HEADER = ["error", "trials", "cells", "first trial"]


def error_table(trials: list[dict]) -> list[dict]:
    """The trials stored with status "error", grouped by message (most frequent first)."""
    groups: dict = {}
    for t in trials:
        if t["status"] != "error":
            continue
        g = groups.setdefault(t.get("error") or "(no message)", {"trials": 0, "cells": set(), "first": t["id"]})
        g["trials"] += 1
        g["cells"].add(t["cell"])
    return [{"error": msg, "trials": g["trials"], "cells": len(g["cells"]), "first": g["first"]}
            for msg, g in sorted(groups.items(), key=lambda kv: -kv[1]["trials"])]


def _error_row(e: dict) -> list[str]:
    msg = e["error"] if len(e["error"]) <= 300 else e["error"][:297] + "..."
    return [msg, str(e["trials"]), str(e["cells"]), e["first"]]


#: the files ``nhstab batch report`` writes besides its figures (figures/<name>.png; an earlier
#: report's files are all replaced)
REPORT_FILES = ("report.html", "report.md", "trials.csv")


def runs_text(runs) -> str:
    """The store's meta ``runs`` (one entry per invocation of the batch) as one sentence each."""
    if not isinstance(runs, list):
        return ""
    out = []
    for i, r in enumerate(runs, 1):
        if not isinstance(r, dict):
            continue
        t = r.get("transfer") if isinstance(r.get("transfer"), dict) else {}
        where = (f"on the Dask cluster at {r.get('scheduler')}" if r.get("executor") == "dask"
                 else f"on {r.get('workers')} local worker process(es)")
        text = f"{i}. {where}: {r.get('stored')} trials stored ({r.get('errors')} failed by error)"
        if isinstance(r.get("wall_s"), (int, float)):
            text += f" in {r['wall_s']:.1f} s"
        if t.get("trials"):
            text += (f"; shipped: map bundles {_kbytes(t.get('bundles_sent_bytes'))} in "
                     f"{t.get('bundle_copies')} copies, per trial {_kbytes(t.get('spec_bytes_per_trial'))} sent "
                     f"(the pickled spec) and {_kbytes(t.get('record_bytes_per_trial'))} received (the pickled record)")
        out.append(text + ".")
    return " ".join(out)


def _kbytes(n) -> str:
    return f"{n / 1000:.1f} kB" if isinstance(n, (int, float)) else "-"


def _md_table(header, rows) -> list[str]:
    """A Markdown table (cells' "|" written "/"), ended by a blank line so that the next paragraph is
    not read as one of its rows."""
    line = lambda cells: "| " + " | ".join(str(c).replace("|", "/") for c in cells) + " |"  # noqa: E731
    return [line(header), "|" + "---|" * len(header), *(line(r) for r in rows), ""]


def _html_table(header, rows) -> list[str]:
    """An HTML table, escaped and closed."""
    return (["<table><tr>" + "".join(f"<th>{html.escape(str(c))}</th>" for c in header) + "</tr>"]
            + ["<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows]
            + ["</table>"])


def _write_report(out, db, trials, config, vers, rows, figs, runs=()) -> None:
    out.write_text("trials.csv", trials_csv(trials))
    _, drawn_note = figure_rows(rows)
    for name, fig in figs.items():
        if fig is not None:
            out.save_figure(fig, f"figures/{name}.png", dpi=90)
    captions = {
        "rates": "Success (goal reached), collision and margin-violation rates per cell, with Wilson 95% intervals.",
        "envelopes": "Tracking error ||x - x0|| while following the first plan: median, 90th and 99th percentile "
                     "over trials; blue: the guaranteed bound of the noiseless linearised loop from each trial's own "
                     "plan and initial error (median over trials): for the future window Proposition 1's 3 alpha "
                     "bound sqrt(e0^T P(0) e0 / lambda_min(P(t))) exp(-3 alpha t) (docs/theory/control-law.md, The "
                     "guarantee; stores from before nhstab recorded it per trial: ||e(0)|| sqrt(p_M/p_m) "
                     "exp(-3 alpha t)), for the frozen-time law its certified bound; none for the past window, "
                     "which has no guarantee. Sensor noise, disturbances and the 50 Hz hold are outside the bound: "
                     "the envelopes may cross it. A cell of fewer than 3 trials has no percentiles: each trial's own "
                     "||e(t)|| is drawn." + drawn_note,
        "distributions": "Minimum executed clearance (orange: the margin, red: contact), final position error, "
                         "replans and replan latency per cell.",
        "tubes": "Predicted error tube against the observed error, per state: RMS over trials of e(t) while following "
                 "the first plan (black) and the RMS each trial's own tube predicts, sqrt(mean of sigma^2 + m^2) "
                 "(blue, dashed)." + drawn_note,
        "paired": "The same seeds under two controllers: each point is one trial.",
        "noise": "Success rate against the noise level, per controller.",
    }
    header = ["cell", "trials", "success", "collision", "margin violation", "median margin [m]", "median min clearance [m]",
              "median final error [m]", "median replans", "replan latency median / p95 [s]"]
    table_rows = [[_label(r), str(r["trials"]) + (f" ({r['errors']} errors)" if r["errors"] else ""),
                   _fmt_rate(r, "success"), _fmt_rate(r, "collision"), _fmt_rate(r, "margin_violation"),
                   _fmt(r["margin_m_median"]), _fmt(r["min_clearance_m_median"]), _fmt(r["final_position_error_m_median"]),
                   _fmt(r["replans_median"]),
                   f"{_fmt(r['replan_latency_median_s'])} / {_fmt(r['replan_latency_p95_s'])}"] for r in rows]
    title = f"nhstab robustness report: {config.get('name', db.parent.name)}"
    errors = error_table(trials)
    n_err = sum(e["trials"] for e in errors)
    outcome = (f" ({len(trials) - n_err} with an outcome, {n_err} failed by error: not counted in any rate, "
               "see Errors)" if n_err else "")
    intro = (f"{len(trials)} trials{outcome} in {len(rows)} cells, root seed {config.get('root_seed')}, "
             f"{config.get('trials')} trials per cell (trial k has the same seed in every cell). "
             f"Every number here is read from `{db.name}`; rates carry Wilson 95% intervals. "
             f"Versions: " + ", ".join(f"{k} {v}" for k, v in vers.items()) + ".")
    ran = runs_text(runs)
    if ran:
        intro += " Runs: " + ran
    md = [f"# {title}", "", intro, "", *_md_table(header, table_rows)]
    trailer_header, trailer_rows = _trailer_table(rows)
    if trailer_rows:
        md += [TRAILER_NOTE, "", *_md_table(trailer_header, trailer_rows)]
    paired = paired_outcomes(trials)
    paired_header = ["map / noise", "controller", "reached where the reference reached", "collisions"]
    paired_rows = [[f"{r['map']} / noise {r['noise']:g}", r["controller"],
                    f"{r['also_reached']}/{r['reference_reached']}"
                    + (f" ({100 * r['fraction']:.1f}%)" if r["reference_reached"] else ""),
                    f"{r['collisions']}/{r['trials']}"] for r in paired]
    if paired:
        md += [f"**Same seeds, against the reference ({paired[0]['reference']}).** On the seeds where the reference "
               "reached the goal, how often each other controller did too; and its collisions over all its "
               "seeds.", "", *_md_table(paired_header, paired_rows)]
    tube_rows = [r for r in rows if r.get("tube_samples")]
    if tube_rows:
        md += [f"**Error tubes.** Coverage: the fraction of the trials' tracking samples (first plan) inside their "
               f"plan's p-tube (p = {tube_rows[0]['tube_probability']:g}; the pose region of the spatial tube, and the "
               "full-state p-ellipsoid), Wilson 95% over samples (correlated within a trial, so too narrow: the "
               "standard deviation of the per-trial fractions and the lowest one are beside it).", "",
               *_md_table(TUBE_HEADER, [_tube_row(r) for r in tube_rows])]
    if errors:
        md += ["## Errors", "", "Trials that failed by error (an exception, not an outcome such as a collision), by "
               "message; each is in `trials.csv` with status `error`.", "",
               *_md_table(ERROR_HEADER, [_error_row(e) for e in errors])]
    for name, fig in figs.items():
        if fig is not None:
            md += [f"![{name}](figures/{name}.png)", "", captions[name], ""]
    missing = left_out(trials, rows, figs)
    if missing:
        md += ["**Figures left out.**", "", *(f"- {name}: {why}." for name, why in missing.items()), ""]
    md += ["Every trial, with its seed and metrics, is in `trials.csv`; replay one with "
           "`nhstab batch replay STORE TRIAL_ID --out DIR`.", ""]
    out.write_text("report.md", "\n".join(md))
    h = ["<!doctype html><html><head><meta charset='utf-8'><title>" + html.escape(title) + "</title>",
         "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
         "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px}"
         "th{background:#f2f2f2}img{max-width:100%}figcaption{font-size:13px;color:#555;margin-bottom:2em}"
         "</style></head><body>", f"<h1>{html.escape(title)}</h1>", f"<p>{html.escape(intro)}</p>",
         *_html_table(header, table_rows)]
    if trailer_rows:
        h += [f"<p>{html.escape(TRAILER_NOTE)}</p>", *_html_table(trailer_header, trailer_rows)]
    if paired:
        h.append(f"<p><b>Same seeds, against the reference ({html.escape(paired[0]['reference'])}).</b> On the seeds "
                 "where the reference reached the goal, how often each other controller did too; and its collisions "
                 "over all its seeds.</p>")
        h += _html_table(paired_header, paired_rows)
    if tube_rows:
        h.append("<h2>Error tubes</h2><p>Coverage of each trial's first-plan p-tube over its tracking samples; "
                 "Wilson 95% over samples (correlated within a trial: too narrow), per-trial spread beside it.</p>")
        h += _html_table(TUBE_HEADER, [_tube_row(r) for r in tube_rows])
    if errors:
        h.append("<h2>Errors</h2><p>Trials that failed by error (an exception, not an outcome such as a collision), "
                 "by message; each is in trials.csv with status error.</p>")
        h += _html_table(ERROR_HEADER, [_error_row(e) for e in errors])
    for name, fig in figs.items():
        if fig is not None:
            h.append(f"<figure><img src='figures/{name}.png' alt='{name}'>"
                     f"<figcaption>{html.escape(captions[name])}</figcaption></figure>")
    if missing:
        h.append("<p><b>Figures left out.</b></p><ul>"
                 + "".join(f"<li>{html.escape(name)}: {html.escape(why)}.</li>" for name, why in missing.items())
                 + "</ul>")
    h.append("<p>Every trial is in <a href='trials.csv'>trials.csv</a>.</p></body></html>")
    out.write_text("report.html", "\n".join(h) + "\n")
