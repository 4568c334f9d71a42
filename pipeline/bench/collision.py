"""``nhstab bench collision``: FCL world build time and pose checks per second."""

from __future__ import annotations

import numpy as np

from ..collision import CollisionWorld
from ..maps import load_map
from ..robot import default_footprint
from .common import _best, machine, maps_dir


def bench_collision(n_poses: int = 20_000, seed: int = 7) -> dict:
    """Build time of the FCL world and pose checks per second for a car footprint on the 512 x 512
    Moving AI rooms map (0.5 m cells) and the nav2 depot map; single calls and batched."""
    maps = maps_dir()
    fp = default_footprint("rwd_car")
    rows = []
    for label, path, options in [("movingai 64room_000 (512x512, 0.5 m cells)", maps / "movingai" / "64room_000.map",
                                  {"cell_size": 0.5}),
                                 ("nav2 depot (604x307, 0.05 m)", maps / "nav2" / "depot.yaml", {})]:
        m = load_map(path, **options)
        build_best, build_median, world = _best(lambda: CollisionWorld.from_map(m), 5)
        rng = np.random.default_rng(seed)
        xmin, ymin, xmax, ymax = m.bounds
        poses = np.column_stack([rng.uniform(xmin, xmax, n_poses), rng.uniform(ymin, ymax, n_poses),
                                 rng.uniform(-np.pi, np.pi, n_poses)])
        single_best, _, single = _best(lambda: [world.is_free(p, fp) for p in poses], 3)
        # the batched path's distance field is built once per world, on first use: timed on its own
        field_best, _, _ = _best(lambda: CollisionWorld.from_map(m).clearance_field(), 3)
        batch_best, _, batch = _best(lambda: world.free_many(poses, fp), 3)
        agree = bool(np.array_equal(np.asarray(single), batch))
        rows.append({"map": label, "objects": world.n_objects, "grid_boxes": world.n_grid_boxes,
                     "build_s": build_best, "build_median_s": build_median,
                     "distance_field_build_s": field_best - build_best,
                     "poses": n_poses, "free_fraction_of_poses": float(np.mean(batch)),
                     "single_checks_per_s": n_poses / single_best, "batched_checks_per_s": n_poses / batch_best,
                     "single_and_batched_agree": agree})
    return {
        "benchmark": "collision", "footprint": fp.describe(), "machine": machine(), "maps": rows,
        "targets": {"build_s_max": 1.0, "checks_per_s_min": 50_000},
        "met": {"build": all(r["build_s"] < 1.0 for r in rows),
                "single": all(r["single_checks_per_s"] >= 50_000 for r in rows),
                "batched": all(r["batched_checks_per_s"] >= 50_000 for r in rows)},
    }


def summary_lines(c: dict) -> list[str]:
    """Rows of the benchmark summary table (benchmark | measure | value | target | met)."""
    lines = []
    for r in c["maps"]:
        lines.append(f"| collision | {r['map']}: build ({r['objects']} objects) | {r['build_s'] * 1e3:.1f} ms | "
                     f"< {c['targets']['build_s_max'] * 1e3:.0f} ms | {'yes' if r['build_s'] < 1 else 'NO'} |")
        total = r["build_s"] + r["distance_field_build_s"]
        lines.append(f"| collision | {r['map']}: build with the batched path's distance field | "
                     f"{total * 1e3:.1f} ms | < {c['targets']['build_s_max'] * 1e3:.0f} ms | "
                     f"{'yes' if total < 1 else 'NO'} |")
        for kind in ("single", "batched"):
            v = r[f"{kind}_checks_per_s"]
            lines.append(f"| collision | {r['map']}: car pose checks/s, {kind} | {v:,.0f} | "
                         f">= {c['targets']['checks_per_s_min']:,} | {'yes' if v >= 50_000 else 'NO'} |")
    return lines
