"""The batch report (``nhstab batch report STORE``): HTML with PNG figures, a Markdown twin, and a
CSV of every trial. Every number in it is read from the store (trials.sqlite), nothing else.

Rates come with Wilson score 95% intervals. The tracking-error envelopes are percentiles over the
trials of ||e(t)|| while each trial follows its first plan, with the gramian bound of Proposition 1,
||e(0)|| sqrt(p_M / p_m) exp(-rate t), rate = 2 alpha p_m / p_M, drawn from each trial's own plan
(median over trials).
"""

from __future__ import annotations

import csv
import html
import io
import math
from pathlib import Path

import numpy as np

from ..report import subplots
from ..records import save_figure, write_text
from .store import Store

Z95 = 1.959963984540054


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float, float, float]:
    """(rate, low, high): the Wilson score interval for a binomial proportion."""
    if n == 0:
        return math.nan, math.nan, math.nan
    p = successes / n
    # centre +- half, clipped to [0, 1]; at p = 0 or 1 one end is the rate itself
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return p, max(0.0, centre - half), min(1.0, centre + half)


def _cells(trials: list[dict]) -> dict:
    cells: dict = {}
    for t in trials:
        cells.setdefault(t["cell"], []).append(t)
    return cells


def _m(t, key):
    return (t.get("metrics") or {}).get(key)


def cell_table(trials: list[dict]) -> list[dict]:
    rows = []
    for cell, ts in _cells(trials).items():
        spec = ts[0]["spec"]["cell_spec"]
        n = len(ts)
        done = [t for t in ts if t["status"] != "error"]
        row = {"cell": cell, "map": spec["map"], "robot": _m(ts[0], "robot") or spec["robot"],
               "controller": spec["controller"], "alpha": spec["alpha"], "delta": spec["delta"],
               "gamma": spec["gamma"], "noise": spec["noise"], "trials": n, "errors": n - len(done)}
        for key, pred in (("success", lambda t: t["status"] == "reached"),
                          ("collision", lambda t: t["status"] == "collision"),
                          ("margin_violation", lambda t: bool(_m(t, "margin_violation")))):
            k = sum(1 for t in done if pred(t))
            rate, lo, hi = wilson(k, len(done))
            row.update({f"{key}_count": k, f"{key}_rate": rate, f"{key}_lo": lo, f"{key}_hi": hi})
        for key in ("min_clearance_m", "final_position_error_m", "replans", "max_error_norm"):
            vals = [_m(t, key) for t in done if _m(t, key) is not None]
            row[f"{key}_median"] = float(np.median(vals)) if vals else math.nan
        if any(_m(t, "jackknife") is not None for t in done):     # a car with trailers
            k = sum(1 for t in done if _m(t, "jackknife"))
            rate, lo, hi = wilson(k, len(done))
            row.update({"jackknife_count": k, "jackknife_rate": rate, "jackknife_lo": lo, "jackknife_hi": hi})
            for key in ("max_abs_hitch_angle_rad", "final_trailer_position_error_m"):
                vals = [_m(t, key) for t in done if _m(t, key) is not None and _m(t, key) == _m(t, key)]
                row[f"{key}_median"] = float(np.median(vals)) if vals else math.nan
        lat = [x for t in done for x in (t.get("timings") or {}).get("replan_latencies_s", [])]
        row["replan_latency_median_s"] = float(np.median(lat)) if lat else math.nan
        row["replan_latency_p95_s"] = float(np.percentile(lat, 95)) if lat else math.nan
        rows.append(row)
    return rows


def trials_csv(trials: list[dict]) -> str:
    keys = ["status", "reached", "collision", "margin_violation", "min_clearance_m", "margin_m",
            "final_position_error_m", "final_heading_error_rad", "replans", "discovered", "rms_error_norm",
            "max_error_norm", "rms_position_error_m", "max_position_error_m", "duration_s", "e0_norm", "p_m", "p_M",
            "rate_bound", "jackknife", "max_abs_hitch_angle_rad", "final_trailer_position_error_m",
            "final_trailer_heading_error_rad"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["id", "cell", "trial", "seed", "map", "robot", "controller", "alpha", "delta", "gamma", "noise",
                *keys, "replan_latencies_s", "error"])
    for t in trials:
        c = t["spec"]["cell_spec"]
        m = t.get("metrics") or {}
        w.writerow([t["id"], t["cell"], t["trial"], t["seed"], c["map"], m.get("robot") or c["robot"],
                    c["controller"], c["alpha"], c["delta"], c["gamma"], c["noise"], t["status"],
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
    return f"{row['map']} / {row['controller']}{gains} / noise {row['noise']:g}"


# ---- figures ---------------------------------------------------------------------------------------



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
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title("Success, collision and margin-violation rates per cell", fontsize=9)
    return fig


def envelope_figure(trials, rows):
    """Per gramian cell (and the baselines beside them): percentiles of ||e(t)|| over trials, and the
    median over trials of each trial's own gramian bound."""
    cells = _cells(trials)
    fig, axes = subplots(len(rows), 1, figsize=(8, 2.2 * len(rows) + 0.6), sharex=True, squeeze=False,
                             layout="constrained")
    for ax, row in zip(axes[:, 0], rows):
        series = [t["series"] for t in cells[row["cell"]] if t.get("series")]
        if not series:
            ax.set_visible(False)
            continue
        dt = series[0]["dt_s"]
        length = max(len(s["error_norm"]) for s in series)
        E = np.full((len(series), length), np.nan)
        for i, s in enumerate(series):
            E[i, :len(s["error_norm"])] = s["error_norm"]
        t = dt * np.arange(length)
        count = np.sum(np.isfinite(E), axis=0)
        keep = count >= max(3, 0.5 * len(series))
        for q, style in ((50, "-"), (90, "--"), (99, ":")):
            ax.semilogy(t[keep], np.nanpercentile(E[:, keep], q, axis=0), "k" + style, lw=1.0, label=f"{q}th percentile")
        bounds = []
        for tr in cells[row["cell"]]:
            m = tr.get("metrics") or {}
            if row["controller"] == "gramian" and m.get("p_m") and m.get("e0_norm") is not None:
                bounds.append(m["e0_norm"] * math.sqrt(m["p_M"] / m["p_m"]) * np.exp(-m["rate_bound"] * t))
        if bounds:
            ax.semilogy(t[keep], np.median(np.array(bounds), axis=0)[keep], color="tab:blue", lw=1.0,
                        label="gramian bound (median over trials)")
        ax.set_ylabel("||e||")
        ax.set_title(_label(row) + f"  ({len(series)} trials)", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, loc="upper right")
    axes[-1, 0].set_xlabel("t [s] (while following the first plan)")
    return fig


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
            margins = {_m(t, "margin_m") for t in trials if _m(t, "margin_m") is not None}
            for mg in margins:
                ax.axvline(mg, color="tab:orange", ls="--", lw=0.8)
            ax.axvline(0.0, color="tab:red", lw=0.8)
        ax.set_title(title, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_yticks(np.arange(1, len(rows) + 1), [_label(r) for r in rows], fontsize=7)
    axes[0].invert_yaxis()
    return fig


def paired_figure(trials):
    """Controllers on the same seeds: each trial's minimum clearance under the gramian law against a
    baseline's, for every (map, noise) cell group where both ran."""
    by = {}
    for t in trials:
        c = t["spec"]["cell_spec"]
        if t["status"] == "error":
            continue
        by.setdefault((c["map"], c["problem"], c["noise"]), {}).setdefault(c["controller"], {})[t["trial"]] = \
            _m(t, "min_clearance_m")
    pairs = [(k, v) for k, v in by.items() if "gramian" in v and len(v) > 1]
    if not pairs:
        return None
    fig, ax = subplots(figsize=(5.5, 5), layout="constrained")
    markers = {"open-loop": "x", "tvlqr": "o"}
    lo, hi = np.inf, -np.inf
    for (mp, _, noise), ctrls in pairs:
        for base, vals in ctrls.items():
            if base == "gramian":
                continue
            ks = sorted(set(vals) & set(ctrls["gramian"]))
            xs = np.array([vals[k] for k in ks], float)
            ys = np.array([ctrls["gramian"][k] for k in ks], float)
            ax.scatter(xs, ys, marker=markers.get(base, "s"), s=18, label=f"{base}, {mp}, noise {noise:g}")
            lo, hi = min(lo, np.nanmin([xs.min(), ys.min()])), max(hi, np.nanmax([xs.max(), ys.max()]))
    ax.plot([lo, hi], [lo, hi], color="0.5", lw=0.8)
    ax.set_xlabel("baseline: min executed clearance [m]")
    ax.set_ylabel("gramian: min executed clearance [m] (same seed)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6)
    ax.set_title("Same seeds, two controllers (above the diagonal: gramian kept more room)", fontsize=8)
    return fig


def noise_figure(rows):
    groups = {}
    for r in rows:
        key = (r["map"], r["controller"], r["alpha"], r["delta"], r["gamma"])
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
    ax.legend(fontsize=7)
    return fig


# ---- the report ----------------------------------------------------------------------------------------

def _fmt_rate(r, key):
    if not r[f"{key}_rate"] == r[f"{key}_rate"]:
        return "-"
    return f"{100 * r[key + '_rate']:.0f}% [{100 * r[key + '_lo']:.0f}, {100 * r[key + '_hi']:.0f}]"


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
    with Store(db) as store:
        trials = store.trials()
        config = store.meta("config", {})
        vers = store.meta("versions", {})
    rows = cell_table(trials)
    figs = {"rates": rates_figure(rows), "envelopes": envelope_figure(trials, rows),
            "distributions": distributions_figure(trials, rows), "paired": paired_figure(trials),
            "noise": noise_figure(rows)}
    written = [write_text(out_dir / "trials.csv", trials_csv(trials))]
    for name, fig in figs.items():
        if fig is not None:
            written.append(save_figure(fig, out_dir / "figures" / f"{name}.png", dpi=90))
    captions = {
        "rates": "Success (goal reached), collision and margin-violation rates per cell, with Wilson 95% intervals.",
        "envelopes": "Tracking error ||x - x0|| while following the first plan: median, 90th and 99th percentile "
                     "over trials; blue: the gramian bound ||e(0)|| sqrt(p_M/p_m) exp(-2 alpha p_m/p_M t) of each "
                     "trial's own plan (median over trials).",
        "distributions": "Minimum executed clearance (orange: the margin, red: contact), final position error, "
                         "replans and replan latency per cell.",
        "paired": "The same seeds under two controllers: each point is one trial.",
        "noise": "Success rate against the noise level, per controller.",
    }
    header = ["cell", "trials", "success", "collision", "margin violation", "median min clearance [m]",
              "median final error [m]", "median replans", "replan latency median / p95 [s]"]
    table_rows = [[_label(r), str(r["trials"]) + (f" ({r['errors']} errors)" if r["errors"] else ""),
                   _fmt_rate(r, "success"), _fmt_rate(r, "collision"), _fmt_rate(r, "margin_violation"),
                   _fmt(r["min_clearance_m_median"]), _fmt(r["final_position_error_m_median"]),
                   _fmt(r["replans_median"]),
                   f"{_fmt(r['replan_latency_median_s'])} / {_fmt(r['replan_latency_p95_s'])}"] for r in rows]
    title = f"nhstab robustness report: {config.get('name', db.parent.name)}"
    intro = (f"{len(trials)} trials in {len(rows)} cells, root seed {config.get('root_seed')}, "
             f"{config.get('trials')} trials per cell (trial k has the same seed in every cell). "
             f"Every number here is read from `{db.name}`; rates carry Wilson 95% intervals. "
             f"Versions: " + ", ".join(f"{k} {v}" for k, v in vers.items()) + ".")
    md = [f"# {title}", "", intro, "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    md += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in table_rows]
    md.append("")
    trailer_header, trailer_rows = _trailer_table(rows)
    if trailer_rows:
        md += [TRAILER_NOTE, "", "| " + " | ".join(trailer_header) + " |", "|" + "---|" * len(trailer_header)]
        md += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in trailer_rows]
        md.append("")
    for name, fig in figs.items():
        if fig is not None:
            md += [f"![{name}](figures/{name}.png)", "", captions[name], ""]
    md += ["Every trial, with its seed and metrics, is in `trials.csv`; replay one with "
           "`nhstab batch replay STORE TRIAL_ID --out DIR`.", ""]
    written.append(write_text(out_dir / "report.md", "\n".join(md)))
    h = ["<!doctype html><html><head><meta charset='utf-8'><title>" + html.escape(title) + "</title>",
         "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
         "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px}"
         "th{background:#f2f2f2}img{max-width:100%}figcaption{font-size:13px;color:#555;margin-bottom:2em}"
         "</style></head><body>", f"<h1>{html.escape(title)}</h1>", f"<p>{html.escape(intro)}</p>",
         "<table><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in header) + "</tr>"]
    h += ["<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in table_rows]
    h.append("</table>")
    if trailer_rows:
        h += [f"<p>{html.escape(TRAILER_NOTE)}</p>",
              "<table><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in trailer_header) + "</tr>"]
        h += ["<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in trailer_rows]
        h.append("</table>")
    for name, fig in figs.items():
        if fig is not None:
            h.append(f"<figure><img src='figures/{name}.png' alt='{name}'>"
                     f"<figcaption>{html.escape(captions[name])}</figcaption></figure>")
    h.append("<p>Every trial is in <a href='trials.csv'>trials.csv</a>.</p></body></html>")
    written.append(write_text(out_dir / "report.html", "\n".join(h) + "\n"))
    return written
