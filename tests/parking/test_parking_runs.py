"""``nhstab run`` on the parking suite: under the default noise, with the gramian law, the car ends
parked within tolerance and never touches anything, on >= 95 % of the runs, for parallel slots of at
least 1.05 x L1 and for perpendicular and angled bays. The runs take the default options except the
sampled tubes' discarded rollouts (``tube: {discards: 0}``, N = 998 rollouts instead of 2,097): the
tubes only decide the cusp replans here, and half the rollouts keep the suite's time in bounds (the
default tube is what tests/execution/test_tight_runs.py and the parking study run).

Every verdict is recomputed here from trajectory.csv and the map file, never taken from run.json:
the last logged pose against the goal, and every logged pose and the motion between them against
every obstacle and the map's bounds, with FCL (``check_path`` at 5 cm) and, independently, with
shapely on the polygons.

The runs are whole ``nhstab run`` processes, two at a time: 14 maps x 2 seeds = 28 runs (about 2
minutes on 2 cores when they plan; failed plans take longer, the run retries; each run also predicts
its sampled error tube and checks the rest of its maneuver at every cusp); >= 95 % means at most 1
failure. The committed parking study (results/parking/study/: every case of the suite, the gramian law
and TVLQR at noise x1, 50 trials per cell) is the larger sample.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from nhstab.collision import CollisionWorld
from nhstab.execution import read_run_csv
from nhstab.geometry import wrap_angle
from nhstab.maps import load_map
from nhstab.parking import read_suite_csv
from nhstab.robot import robot_from_spec

shapely = pytest.importorskip("shapely")
from shapely.geometry import Polygon as SPolygon  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
FOLDER = ROOT / "maps" / "parking"
SEEDS = (0, 1)
#: the run's default goal tolerance (checked against run.json's inputs, then applied here)
TOLERANCE = {"position_m": 0.3, "heading_rad": 0.2}


def _cases() -> list[str]:
    """Parallel slots >= 1.05 x L1, the one-way perpendicular aisle and the tight angled aisles, both cars."""
    out = []
    for r in read_suite_csv(FOLDER / "suite.csv"):
        if r["kind"] == "parallel" and r["factor"] >= 1.05 - 1e-9:
            out.append(r["name"])
        elif r["kind"] == "perpendicular" and abs(r["factor"] - 1.3) < 1e-9:
            out.append(r["name"])
        elif r["kind"].startswith("angled") and abs(r["factor"] - 1.5) < 1e-9:
            out.append(r["name"])
    return out


def _run(name: str, seed: int, out: Path) -> int:
    config = out.with_suffix(".config.yaml")
    config.write_text("tube: {discards: 0}\n")
    cmd = [sys.executable, "-m", "nhstab.cli.main", "run", str(FOLDER / f"{name}.yaml"), "--seed", str(seed),
           "--controller", "gramian", "--config", str(config), "--out", str(out)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600).returncode


def verdict(name: str, out: Path) -> tuple[bool, str]:
    """Parked and untouched, from trajectory.csv and the map alone."""
    if not (out / "trajectory.csv").is_file():
        return False, "no trajectory.csv"
    csv = read_run_csv(out / "trajectory.csv")
    poses = np.stack([csv["x"], csv["y"], csv["theta"]], axis=1)
    if len(poses) < 2:
        return False, "no motion (no plan?)"
    inputs = json.loads((out / "run.json").read_text())["inputs"]
    assert inputs["options"]["tolerance"] == TOLERANCE
    assert inputs["options"]["controller"]["kind"] == "gramian"
    m = load_map(FOLDER / f"{name}.yaml")
    robot = robot_from_spec(m.robot)
    goal = m.goal.as_array()
    # FCL: every logged pose and the motion between them (5 cm), against every obstacle and the bounds
    check = CollisionWorld.from_map(m, "all").check_path(poses, robot.footprint, margin=0.0, resolution=0.05)
    if not check.clear:
        return False, f"collision (FCL) at {np.round(check.first_conflict_pose, 3).tolist()}"
    # shapely, independently: every logged pose's body against the union of the obstacles and the bounds
    union = shapely.union_all([SPolygon(s.vertices) for s in (*m.obstacles, *m.unknown_obstacles)])
    fp = robot.footprint.vertices
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    xs = poses[:, 0, None] + c[:, None] * fp[:, 0] - s[:, None] * fp[:, 1]
    ys = poses[:, 1, None] + s[:, None] * fp[:, 0] + c[:, None] * fp[:, 1]
    bodies = shapely.polygons(np.stack([xs, ys], axis=-1))
    if shapely.intersects(bodies, union).any():
        k = int(np.argmax(shapely.intersects(bodies, union)))
        return False, f"collision (shapely) at {np.round(poses[k], 3).tolist()}"
    xmin, ymin, xmax, ymax = m.bounds
    if xs.min() <= xmin or ys.min() <= ymin or xs.max() >= xmax or ys.max() >= ymax:
        return False, "left the map"
    err_pos = math.hypot(*(poses[-1, :2] - goal[:2]))
    err_head = abs(wrap_angle(poses[-1, 2] - goal[2]))
    if err_pos > TOLERANCE["position_m"] or err_head > TOLERANCE["heading_rad"]:
        return False, f"not parked: ends {err_pos:.3f} m, {err_head:.3f} rad from the goal"
    return True, f"parked {err_pos:.3f} m, {err_head:.3f} rad from the goal, clearance {check.min_clearance:.3f} m"


@pytest.fixture(scope="module")
def suite_runs(tmp_path_factory):
    """The 28 runs, once for the module: (name, seed, output folder, exit code) each."""
    tmp_path = tmp_path_factory.mktemp("suite")
    jobs = [(name, seed, tmp_path / f"{name}-{seed}") for name in _cases() for seed in SEEDS]
    with ThreadPoolExecutor(max_workers=2) as pool:
        codes = list(pool.map(lambda j: _run(*j), jobs))
    return [(name, seed, out, code) for (name, seed, out), code in zip(jobs, codes)]


@pytest.mark.slow
def test_gramian_parks_without_touching_on_95_percent_of_runs(suite_runs):
    assert len(suite_runs) == 28
    results = []
    for name, seed, out, code in suite_runs:
        ok, why = verdict(name, out)
        results.append((name, seed, code, ok, why))
        # the run's own exit code may not claim more than the recomputed verdict
        assert not (code == 0 and not ok), f"{name} seed {seed}: nhstab run says reached, but {why}"
    failed = [r for r in results if not r[3]]
    report = "\n".join(f"{n} seed {s}: exit {c}: {w}" for n, s, c, _, w in results)
    assert len(failed) <= 0.05 * len(results), f"{len(failed)} of {len(results)} runs failed:\n{report}"


@pytest.mark.slow
def test_verdict_recomputes_from_the_files(tmp_path, suite_runs):
    """The checker on one of the suite's runs (the rwd car into the 60-degree bay off the 1.5 x aisle,
    seed 0) and on doctored copies of its trajectory: a pose moved into a parked car is a collision, a
    last pose moved away is not parked."""
    name = "angled60_rwd_car_aisle150"
    out, code = next((o, c) for n, s, o, c in suite_runs if n == name and s == 0)
    ok, why = verdict(name, out)
    assert (code == 0) == ok, why
    if not ok:
        pytest.skip(f"the run itself did not park ({why}); doctoring needs a parked run")
    text = (out / "trajectory.csv").read_text().splitlines()
    header = text[0].split(",")
    ix = next(i for i, h in enumerate(header) if h.split(" [")[0] == "x")
    iy = next(i for i, h in enumerate(header) if h.split(" [")[0] == "y")
    m = load_map(FOLDER / f"{name}.yaml")
    parked_car = next(s for s in m.obstacles if abs(SPolygon(s.vertices).area - 4.2 * 1.8) < 1e-6)
    cx, cy = SPolygon(parked_car.vertices).centroid.coords[0]

    def doctored(row_index, x, y, folder):
        folder.mkdir()
        rows = [r.split(",") for r in text]
        rows[row_index][ix], rows[row_index][iy] = repr(x), repr(y)
        (folder / "trajectory.csv").write_text("\n".join(",".join(r) for r in rows) + "\n")
        (folder / "run.json").write_text((out / "run.json").read_text())
        return verdict(name, folder)

    ok, why = doctored(len(text) // 2, cx, cy, tmp_path / "hit")
    assert not ok and "collision (FCL)" in why
    last = text[-1].split(",")
    ok, why = doctored(len(text) - 1, float(last[ix]) + 0.5, float(last[iy]), tmp_path / "far")
    assert not ok and ("not parked" in why or "collision" in why)
