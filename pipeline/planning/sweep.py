"""The sweep behind the default stabilizer parameters per robot (``nhstab plan sweep``).

For each robot, plan once on a bundled map (fixed seed), then compute the gain schedule along that
nominal for a grid of alpha and delta (gamma = 1) and record the smallest gramian eigenvalue, the
largest gain norm and the rates. Defaults: among the settings whose largest gain norm is within a
stated bound, the one with the largest printed rate 2 alpha p_m / p_M. (The guaranteed rate is 3 alpha
(docs/theory/control-law.md, The guarantee), which alone would simply pick the largest alpha under the
gain bound; the printed rate also rewards a well-conditioned P, i.e. a small constant sqrt(p_M / p_m)
in the bound, and is what chose the committed defaults.) The bound is max ||K|| <= 50. It keeps a
controller sampled at 50 Hz with zero-order hold well inside its stability limit (dt ||B K|| < 2).
It also keeps the feedback from turning the default 2 cm position noise of the sensor into more than
about 1 m/s or 1 rad/s of input, the robots' own limits.
"""

from __future__ import annotations

from ..control import GAIN_BOUND, StabilizerOptions, compute_schedule
from ..errors import SingularGramianError
from ..maps import load_map
from ..models import MODELS
from ..robot import default_robot
from . import PathOptions, plan

#: the robots swept and their (alpha, delta) grids: each model's ``sweep_grid`` (:class:`nhstab.models.Model`)
GRID = {name: cls.sweep_grid for name, cls in MODELS.items() if cls.sweep_grid is not None}


def sweep(map_path, seed: int = 1) -> dict:
    m = load_map(map_path)
    rows = []
    for name, grid in GRID.items():
        robot = default_robot(name)
        r = plan(m, robot, m.start.as_array(), m.goal.as_array(),
                 PathOptions(time_limit_s=5.0, seed=seed, margin=0.1))
        if r.nominal is None:
            rows.append({"robot": name, "error": r.message})
            continue
        for alpha in grid["alpha"]:
            for delta in grid["delta"]:
                entry = {"robot": name, "alpha": alpha, "delta": delta, "gamma": 1.0,
                         "plan_length_m": r.metrics["length_m"], "plan_duration_s": r.metrics["duration_s"]}
                try:
                    d = compute_schedule(r.nominal, StabilizerOptions(
                        alpha=alpha, delta=delta, end_strategy=robot.stabilizer.end_strategy)).diagnostics
                    entry.update({k: d[k] for k in ("h_min_eigenvalue", "max_gain_norm", "rate_bound",
                                                    "rate_bound_printed", "p_m", "p_M")})
                except SingularGramianError as exc:
                    entry["error"] = str(exc)
                rows.append(entry)
    chosen = {}
    for name in GRID:
        ok = [r for r in rows if r["robot"] == name and "max_gain_norm" in r and r["max_gain_norm"] <= GAIN_BOUND]
        if ok:
            best = max(ok, key=lambda r: r["rate_bound_printed"])
            chosen[name] = {"alpha": best["alpha"], "delta": best["delta"], "gamma": 1.0}
    return {"map": str(map_path), "seed": seed, "gain_bound": GAIN_BOUND, "rows": rows, "chosen": chosen}


def sweep_markdown(result: dict) -> str:
    lines = ["# Stabilizer parameters per robot: the sweep", "",
             f"Produced by `nhstab sweep` on `{result['map']}` (seed {result['seed']}): one plan per robot, "
             "then the gain schedule along it for each (alpha, delta), gamma = 1, 6-alpha weighting.",
             f"Chosen: the largest printed rate 2 alpha p_m/p_M (the guaranteed rate is 3 alpha; the printed one "
             "also rewards a well-conditioned P) among settings with max ||K|| <= "
             f"{result['gain_bound']:g} (so that a "
             "50 Hz zero-order-hold controller stays well inside dt ||B K|| < 2, and 2 cm of sensor noise "
             "becomes at most about 1 m/s or 1 rad/s of input).", "",
             "| robot | alpha | delta [s] | min eig H | max gain norm | printed 2a pm/pM [1/s] | chosen |",
             "|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        c = result["chosen"].get(r["robot"], {})
        mark = "yes" if c.get("alpha") == r.get("alpha") and c.get("delta") == r.get("delta") else ""
        if "max_gain_norm" in r:
            lines.append(f"| {r['robot']} | {r['alpha']:g} | {r['delta']:g} | {r['h_min_eigenvalue']:.3g} | "
                         f"{r['max_gain_norm']:.3g} | {r['rate_bound_printed']:.3g} | {mark} |")
        else:
            lines.append(f"| {r['robot']} | {r.get('alpha', '-')} | {r.get('delta', '-')} | singular | - | - | |")
    return "\n".join(lines) + "\n"
