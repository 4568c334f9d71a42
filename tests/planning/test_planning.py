"""Plans on real maps, re-checked independently; plan -> stabilize -> simulate through cusps; CLI."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from clitools import only_line
from nhstab.cli.main import cli
from nhstab.collision import CollisionWorld
from nhstab.maps import load_map
from nhstab.maps.base import Circle, Polygon
from nhstab.models import make_model
from nhstab.planning import PathOptions, TimingOptions, plan, pose_columns
from nhstab.planning.cars import car_nominal, direction_reversals
from nhstab.planning.geometric import GeometricPath, path_directions
from nhstab.robot import default_footprint, make_robot
from nhstab.simulation import simulate_tracking
from shapely import STRtree
from shapely.geometry import Point, box
from shapely.geometry import Polygon as SPolygon

MAPS = Path(__file__).parents[2] / "maps"


def shapely_obstacles(m):
    """The map's known obstacles as shapely geometry, built from the map value alone (not FCL):
    polygons, circles (as exact distances), occupied grid cells as boxes, and the bounds' outside."""
    geoms = [SPolygon(o.vertices) for o in m.obstacles if isinstance(o, Polygon)]
    for g in m.grids:
        ii, jj = np.nonzero(g.occupied)
        corners = [(g.cell_to_world(i - 0.5, j - 0.5), g.cell_to_world(i + 0.5, j + 0.5)) for i, j in zip(ii, jj)]
        geoms += [box(min(a[0], b[0]), min(a[1], b[1]), max(a[0], b[0]), max(a[1], b[1])) for a, b in corners]
    xmin, ymin, xmax, ymax = m.bounds
    outside = box(xmin - 5, ymin - 5, xmax + 5, ymax + 5).difference(box(xmin, ymin, xmax, ymax))
    return STRtree(geoms + [outside]), geoms + [outside], [o for o in m.obstacles if isinstance(o, Circle)]


def independent_min_clearance(m, fp, poses, reach=2.0):
    tree, geoms, circles = shapely_obstacles(m)
    worst = np.inf
    for p in poses:
        shape = SPolygon(fp.outline_at(p, 96)) if fp.radius is None else Point(p[0], p[1])
        pad = 0.0 if fp.radius is None else fp.radius
        near = tree.query(shape.buffer(reach))
        d = min([shape.distance(geoms[k]) - pad for k in near] + [reach])
        d = min([d] + [shape.distance(Point(*c.center)) - c.radius - pad for c in circles])
        worst = min(worst, d)
    return worst


CASES = [
    ("ours/cluttered_room.yaml", {}, "map"),
    ("ours/warehouse_corridor.yaml", {}, "map"),
    ("nav2/depot.yaml", {}, ((2.0, 2.0, 0.0), (27.0, 12.0, 3.0))),
    # a Moving AI street map at 1 m per cell, one of its own scenarios (the rooms map's 1-cell doors are
    # a narrow-passage problem whose RRTConnect success in a fixed budget depends on machine speed)
    ("bench-mr/moving_ai_scenarios/Berlin_0_256.map", {"cell_size": 1.0}, "problem200"),
    ("bench-mr/polygon_mazes/parking1.svg", {}, "problem0"),
]


@pytest.mark.slow
@pytest.mark.parametrize("rel,opts,poses", CASES, ids=[c[0] for c in CASES])
def test_unicycle_plans_on_real_maps(rel, opts, poses):
    m = load_map(MAPS / rel, **opts)
    if poses == "map":
        s, g = m.start.as_array(), m.goal.as_array()
    elif isinstance(poses, str) and poses.startswith("problem"):
        p = m.problems[int(poses[len("problem"):])]
        s, g = p.start.as_array(), p.goal.as_array()
    else:
        s, g = np.array(poses[0]), np.array(poses[1])
    model, fp = make_model("unicycle"), default_footprint("unicycle")
    margin = 0.1
    r = plan(m, make_robot(model, footprint=fp), s, g, PathOptions(turning_radius=0.5, time_limit_s=5.0, seed=2, margin=margin))
    assert r.ok, r.message
    poses_x = r.nominal.x[:, pose_columns(model)]
    # collision-free by the margin, re-checked independently of FCL (shapely), every 5th grid point
    assert independent_min_clearance(m, fp, poses_x[::5]) >= margin - 1e-6
    assert r.nominal.feasibility_residual() < 1e-3
    assert np.linalg.norm(poses_x[0, :2] - s[:2]) < 1e-9 and np.linalg.norm(poses_x[-1, :2] - g[:2]) < 2e-2
    assert np.all(np.isfinite(r.schedule.K)) and len(r.schedule.t) == len(r.nominal.t)
    assert np.all(np.abs(r.nominal.u) <= model.input_limits()[:, 1] + 1e-9)


@pytest.mark.slow
def test_plan_stabilize_simulate_through_cusps():
    """A Reeds-Shepp plan with at least two cusps; noiseless closed loop from an initial error: the
    error converges and the executed path keeps its clearance (re-checked with shapely)."""
    m = load_map(MAPS / "ours/cluttered_room.yaml")
    model, fp = make_model("unicycle"), default_footprint("unicycle")
    r = plan(m, make_robot(model, footprint=fp), m.start.as_array(), m.goal.as_array(),
             PathOptions(turning_radius=0.5, time_limit_s=5.0, seed=1, margin=0.1))
    assert r.ok and r.metrics["cusps"] >= 2
    e0 = np.array([0.05, -0.04, 0.05])
    run = simulate_tracking(r.schedule, r.nominal.x[0] + e0, rtol=1e-8, atol=1e-12)
    assert run.status == "completed"
    en = run.error_norm
    assert en[-1] < 0.05 * en[0]
    # the error shrinks over the plan: its largest value in the last quarter is below the first quarter's
    q = len(en) // 4
    assert en[-q:].max() < en[:q].max()
    executed = run.x[::10, pose_columns(model)]
    assert independent_min_clearance(m, fp, executed) > 0.0


def _cli(args):
    return CliRunner().invoke(cli, args)


def test_plan_cli_writes_files(tmp_path):
    res = _cli(["plan", str(MAPS / "ours/cluttered_room.yaml"), "--seed", "1", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "plan.json").read_text())
    assert doc["status"] == "ok" and doc["metrics"]["cusps"] >= 0
    assert doc["inputs"]["feasibility_residual_m"] < 1e-3
    assert 0 < doc["timing"]["outputs_s"] < 60                  # what the benchmark reads
    header = (tmp_path / "trajectory.csv").read_text().splitlines()[0]
    assert header == "t [s],x [m],y [m],theta [rad],v [m/s],omega [rad/s]"
    assert (tmp_path / "plan.png").stat().st_size > 10_000
    assert set(np.load(tmp_path / "trajectory.npz").files) == {"t", "x", "u"}


@pytest.mark.slow
def test_plan_cli_without_the_figure_skips_matplotlib(tmp_path):
    """--no-figure: every file but plan.png, and matplotlib's drawing stack (matplotlib.figure, the bulk
    of its import time) is never imported (a new process; the distance field of a vector map uses
    matplotlib.path for its point-in-polygon test)."""
    import subprocess
    import sys

    code = ("import sys\nfrom nhstab.cli.main import main\n"
            f"sys.argv = ['nhstab', 'plan', {str(MAPS / 'ours/cluttered_room.yaml')!r}, '--seed', '1', '--no-figure', "
            f"'--out', {str(tmp_path)!r}]\n"
            "try:\n    main()\nexcept SystemExit as exc:\n    assert not exc.code, exc.code\n"
            "print('matplotlib.figure' in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "False"
    assert not (tmp_path / "plan.png").exists()
    assert {"plan.json", "trajectory.csv", "trajectory.npz", "tube.npz"} <= {p.name for p in tmp_path.iterdir()}




@pytest.mark.parametrize("args,needles", [
    (["--start", "100,2,0"], ["start", "bounds"]),
    (["--goal", "4.0,4.5,0"], ["goal", "overlaps"]),
    (["--planner", "astar"], ["'--planner'", "astar"]),
    (["--time-limit", "0"], ["'--time-limit'"]),
    (["--turning-radius", "0"], ["'--turning-radius'"]),
    (["--turning-radius", "-1"], ["'--turning-radius'"]),
    (["--robot", "hovercraft"], ["'--robot'", "hovercraft"]),
])
def test_plan_cli_bad_requests(tmp_path, args, needles):
    only_line(_cli(["plan", str(MAPS / "ours/cluttered_room.yaml"), "--out", str(tmp_path / "o"), *args]), 2, *needles)
    assert not (tmp_path / "o").exists()


def test_plan_cli_no_plan_exit_3(tmp_path):
    """A goal enclosed by walls: a valid request with no plan: exit 3, what was tried, nothing written."""
    enclosed = tmp_path / "enclosed.yaml"
    enclosed.write_text("bounds: [0, 0, 20, 10]\nobstacles:\n"
                        "  - box: {center: [15, 2.5], size: [6, 0.4]}\n  - box: {center: [15, 7.5], size: [6, 0.4]}\n"
                        "  - box: {center: [12.2, 5], size: [0.4, 5.4]}\n  - box: {center: [17.8, 5], size: [0.4, 5.4]}\n"
                        "start: [3, 5, 0]\ngoal: [15, 5, 0]\nrobot: {model: unicycle}\n")
    res = _cli(["plan", str(enclosed), "--time-limit", "0.3", "--out", str(tmp_path / "o")])
    assert res.exit_code == 3 and "Traceback" not in res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 2, lines
    assert all(n in lines[0] for n in ("nhstab: no plan", "rrtconnect", "0.3 s", "seed 0")), lines[0]
    # the second line says why: the goal's room is walled in (the unicycle's radius 0.3 m)
    assert lines[1].startswith("likely cause: the known obstacles: no way from start to goal") and "0.3 m" in lines[1]
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["rwd_car", "fwd_car"])
@pytest.mark.parametrize("where", ["depot", "berlin_1m", "parking3", "ours_parking_lot", "ours_warehouse"])
def test_car_plans_on_real_maps(robot, where):
    from nhstab.planning import default_turning_radius
    from nhstab.planning.problems import benchmr_center_to_rear_axle, random_problems

    model, fp = make_model(robot), default_footprint(robot)
    if where == "depot":
        m = load_map(MAPS / "nav2/depot.yaml")
        s, g = random_problems(CollisionWorld.from_map(m), fp, 1, seed=5, clearance=0.6, min_distance=10.0)[0]
    elif where == "berlin_1m":
        m = load_map(MAPS / "bench-mr/moving_ai_scenarios/Berlin_0_256.map", cell_size=1.0)
        s, g = m.problems[200].start.as_array(), m.problems[200].goal.as_array()
    elif where == "parking3":
        # (in parking1 and parking2 Bench-MR's poses put a 4.2 m car over the bounds or a parked car)
        m = load_map(MAPS / "bench-mr/polygon_mazes/parking3.svg")
        world = CollisionWorld.from_map(m)
        length = fp.vertices[:, 0].max() - fp.vertices[:, 0].min()
        # the first Bench-MR problem whose poses, moved from the car's centre to its rear axle, are free
        for p in m.problems:
            s, g = (benchmr_center_to_rear_axle(q.as_array(), length, -fp.vertices[:, 0].min()) for q in (p.start, p.goal))
            if world.is_free(s, fp, 0.2) and world.is_free(g, fp, 0.2):
                break
        else:
            pytest.fail("no Bench-MR parking3 problem fits this car")
    else:
        m = load_map(MAPS / ("ours/parking_lot.yaml" if where == "ours_parking_lot" else "ours/warehouse_corridor.yaml"))
        s, g = m.start.as_array(), m.goal.as_array()
    margin = 0.1
    r = plan(m, make_robot(model, footprint=fp), s, g, PathOptions(turning_radius=default_turning_radius(model), time_limit_s=5.0, seed=2,
                                              margin=margin))
    assert r.ok, r.message
    x = r.nominal.x
    poses_x = x[:, pose_columns(model)]
    assert independent_min_clearance(m, fp, poses_x[::10]) >= margin - 1e-6
    assert r.nominal.feasibility_residual() < 1e-3
    j = list(model.state_names).index("phi")
    assert np.max(np.abs(x[:, j])) <= model.max_steer + 1e-9                   # steering within its limit
    assert np.max(np.abs(np.diff(x[:, j]))) <= model.max_steer_rate * r.nominal.t[1] * 1.01 + 1e-9   # no jump
    assert np.all(np.abs(r.nominal.u) <= model.input_limits()[:, 1] * 1.001 + 1e-9)
    assert np.linalg.norm(poses_x[-1, :2] - g[:2]) < 1e-6
    assert np.all(np.isfinite(r.schedule.K)) and r.metrics["max_gain_norm"] < 1e3
    # the car reverses where the path does, and nowhere else (runs of 5 cm or more, both counted alike)
    reversals = direction_reversals(poses_x)
    assert reversals == r.metrics["direction_reversals"] == direction_reversals(r.path.samples)
    assert reversals <= r.metrics["cusps"]


def test_default_stabilizer_parameters_are_the_committed_sweeps_choice():
    """The per-robot defaults are what `nhstab sweep` chose (results/planning/sweep.json)."""
    from nhstab.robot import default_robot

    sweep = json.loads((Path(__file__).parents[2] / "results" / "planning" / "sweep.json").read_text())
    assert sweep["chosen"] == {name: {k: getattr(default_robot(name).stabilizer, k) for k in ("alpha", "delta", "gamma")}
                               for name in sweep["chosen"]}
    for row in sweep["rows"]:
        chosen = sweep["chosen"][row["robot"]]
        if (row["alpha"], row["delta"]) == (chosen["alpha"], chosen["delta"]):
            assert row["max_gain_norm"] <= sweep["gain_bound"]


# ---------------------------------------------------------------------------------------------
# the car's local planner on a synthetic path (no OMPL): constant-v1 first, then splitting, then phased
# ---------------------------------------------------------------------------------------------
CAR_KAPPA = 0.5 * np.tan(0.6) / 2.5     # a curvature well inside the rwd_car's limit tan(0.6) / L


def synthetic_path(segments, step=0.005) -> GeometricPath:
    """Exact samples of a path of (length, curvature dtheta/dsigma, direction) segments from (0, 0, 0)."""
    pose, sigma0 = np.zeros(3), 0.0
    samples, sigmas = [pose[None]], [np.zeros(1)]
    for length, kappa, d in segments:
        s = np.linspace(0.0, length, int(round(length / step)) + 1)[1:]
        th = pose[2] + kappa * s
        if kappa:
            x = pose[0] + d * (np.sin(th) - np.sin(pose[2])) / kappa
            y = pose[1] - d * (np.cos(th) - np.cos(pose[2])) / kappa
        else:
            x, y = pose[0] + d * s * np.cos(th), pose[1] + d * s * np.sin(th)
        samples.append(np.column_stack([x, y, th]))
        sigmas.append(sigma0 + s)
        pose, sigma0 = samples[-1][-1], sigma0 + length
    samples, sigma = np.vstack(samples), np.concatenate(sigmas)
    direction, cusps = path_directions(samples)
    return GeometricPath("exact", "synthetic", samples[[0, -1]], samples, sigma, direction, float(sigma[-1]), cusps,
                         0.0, 0, 0.0, PathOptions(turning_radius=1.0, margin=0.1))


# left 3 m, right 3 m (the inflection at a whole number of metres, where a waypoint would fall), a cusp,
# back 2 m straight and 1.5 m on a left arc
S_CURVE = [(3.0, CAR_KAPPA, 1), (3.0, -CAR_KAPPA, 1), (2.0, 0.0, -1), (1.5, CAR_KAPPA, -1)]


def _car_nominal(path, **kwargs):
    from nhstab.maps.base import Map

    model, fp = make_model("rwd_car"), default_footprint("rwd_car")
    world = CollisionWorld.from_map(Map("empty", (-20.0, -20.0, 20.0, 20.0)))
    return model, car_nominal(model, path, TimingOptions(), world, fp, 0.1, **kwargs)


def _check_exact(model, path, nominal):
    assert nominal.feasibility_residual() < 1e-3
    np.testing.assert_allclose(nominal.x[0, :3], path.samples[0], atol=1e-12)
    np.testing.assert_allclose(nominal.x[-1, :3], path.samples[-1], atol=1e-9)
    phi = nominal.x[:, 3]
    assert np.abs(phi).max() <= model.max_steer + 1e-9
    assert np.abs(np.diff(phi)).max() <= model.max_steer_rate * nominal.t[1] * 1.01 + 1e-9


def test_car_nominal_drives_each_run_one_way():
    path = synthetic_path(S_CURVE)
    assert path.cusps == 1
    model, (nominal, info) = _car_nominal(path)
    _check_exact(model, path, nominal)
    assert info["phased_pieces"] == 0 and info["subdivisions"] == 0
    assert info["direction_reversals"] == direction_reversals(nominal.x[:, :3]) == 1
    # forward until the cusp, then backward: v never has the wrong sign (0 while steering in place)
    v, t_cusp = nominal.u[:, 0], nominal.t[np.argmin(np.hypot(*(nominal.x[:, :2] - path.samples[1200, :2]).T))]
    assert np.all(v[nominal.t < t_cusp - 1e-9] >= 0) and np.all(v[nominal.t > t_cusp + 2.0] <= 0)
    # the nominal stays within a few centimetres of the path
    gap = np.hypot(*(nominal.x[:, None, :2] - path.samples[None, ::10, :2]).transpose(2, 0, 1)).min(axis=1)
    assert gap.max() < 0.05


def test_car_nominal_splits_failing_pieces_before_falling_back(monkeypatch):
    """Constant-v1 pieces longer than 0.6 m are refused: they are split (no phased pieces, no extra
    reversals); with splitting ruled out (min_spacing above every piece) the phased sinusoids take
    over, exactly, at the price of back-and-forth motion."""
    import nhstab.planning.cars as cars
    from nhstab.errors import InputError

    real = cars.steer_car

    def refuse_long(model, xa, xb, T=None, mode="phased", **kw):
        if mode == "constant_v1" and np.hypot(*(xb[:2] - xa[:2])) > 0.6:
            raise InputError("xf", "a short piece (test)", xb)
        return real(model, xa, xb, T, mode=mode, **kw)

    monkeypatch.setattr(cars, "steer_car", refuse_long)
    path = synthetic_path(S_CURVE)
    model, (nominal, info) = _car_nominal(path)
    _check_exact(model, path, nominal)
    assert info["subdivisions"] > 0 and info["phased_pieces"] == 0 and info["direction_reversals"] == 1
    model, (nominal, info) = _car_nominal(path, min_spacing=100.0)
    _check_exact(model, path, nominal)
    assert info["subdivisions"] == 0 and info["phased_pieces"] == info["pieces"] - info["steer_in_place"]
    assert info["direction_reversals"] > 1


def test_direction_reversals():
    def line(moves):
        """Poses along the x axis, heading 0, moving by the given signed distances in 1 cm steps."""
        x = np.concatenate([[0.0], *[np.full(int(round(abs(m) / 0.01)), np.sign(m) * 0.01) for m in moves]]).cumsum()
        return np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])

    assert direction_reversals(line([1.0, -0.5, 0.3])) == 2
    assert direction_reversals(line([1.0, -0.02, 0.3])) == 0          # a 2 cm run is no reversal
    assert direction_reversals(line([1.0, -0.5, 0.02, -0.3])) == 1
    assert direction_reversals(line([-0.2, -0.5])) == 0
    assert direction_reversals(np.zeros((5, 3))) == 0                 # standing still
    assert direction_reversals(line([1.0, -0.5]), min_run=0.6) == 0
