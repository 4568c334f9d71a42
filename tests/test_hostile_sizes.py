"""Hostile sizes: inputs whose size or magnitude made nhstab crash or run unbounded.

Each test checks the bound (one line naming the key, exit code 2, no traceback) or the work's growth,
never a wall-clock time: machines are noisy.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from clitools import invoke, one_line
from nhstab.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
M = ROOT / "maps/ours/cluttered_room.yaml"






def comb(teeth: int, x0: float = 2.0, y0: float = 2.0, width: float = 2.0, reach: float = 4.0,
         height: float = 5.0) -> np.ndarray:
    """A simple ring of ``4 teeth + 2`` vertices whose teeth are long parallel diagonal edges: every
    edge's bounding box overlaps almost every other's (the worst case of tests by bounding boxes)."""
    d = width / teeth
    pts = []
    for i in range(teeth):
        x = x0 + i * d
        pts += [(x, y0), (x + reach, y0 + height), (x + reach + d / 2, y0 + height), (x + d / 2, y0)]
    pts += [(x0 + (teeth - 1) * d + d / 2, y0 - 0.5), (x0, y0 - 0.5)]
    return np.array(pts)


def star(k: int, cx: float = 6.0, cy: float = 4.5) -> np.ndarray:
    a = 2 * np.pi * np.arange(k) / k
    r = 2.0 + 0.8 * (np.arange(k) % 2)
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])


def python_calls(fn, *args) -> int:
    """How many Python functions ``fn(*args)`` calls (a measure of work that does not depend on the
    machine's speed: the loops of a pure-Python algorithm show up as calls)."""
    count = 0

    def prof(frame, event, arg):
        nonlocal count
        if event == "call":
            count += 1

    sys.setprofile(prof)
    try:
        fn(*args)
    finally:
        sys.setprofile(None)
    return count


# ---- polygons: map obstacles and footprints ------------------------------------------------------

def yaml_map(path: Path, ring: np.ndarray, key: str = "polygon", start="[1.0, 1.0, 0.0]") -> Path:
    pts = ", ".join(f"[{x:.9f}, {y:.9f}]" for x, y in ring)
    path.write_text(f"name: big\nbounds: [0.0, 0.0, 12.0, 9.0]\nobstacles:\n  - {key}: [{pts}]\n"
                    f"start: {start}\ngoal: [11.0, 1.0, 0.0]\nrobot: {{model: unicycle}}\n")
    return path


def test_polygons_beyond_the_vertex_bound_are_refused_naming_the_key(tmp_path):
    from nhstab.limits import MAX_POLYGON_VERTICES
    from nhstab.maps.base import Polygon

    assert MAX_POLYGON_VERTICES == 10_000
    big = star(MAX_POLYGON_VERTICES + 2)
    one_line(invoke("map", "info", yaml_map(tmp_path / "p.yaml", big)), 2, "obstacles[0].polygon",
             "at most 10,000 [x, y] points", "10002")
    line = np.column_stack([np.linspace(1, 11, 5_002), np.full(5_002, 5.0)])
    one_line(invoke("map", "info", yaml_map(tmp_path / "l.yaml", line, "line")), 2, "obstacles[0].line",
             "at most 5,001 [x, y] points")
    with pytest.raises(InputError, match="'polygon' must be at most 10,000 vertices"):
        Polygon(big)
    robot = tmp_path / "robot.yaml"
    robot.write_text("model: unicycle\nfootprint:\n  polygon: ["
                     + ", ".join(f"[{x:.6f}, {y:.6f}]" for x, y in star(10_002, 0.0, 0.0) / 10) + "]\n")
    one_line(invoke("plan", M, "--robot-config", robot, "--out", tmp_path / "o"), 2, "robot.footprint.polygon",
             "10,000")
    assert not (tmp_path / "o").exists()


def test_the_triangulation_does_no_python_work_per_vertex():
    """Ear clipping in Python made millions of calls on a few thousand vertices (a 40,000-vertex map took
    minutes); GEOS's triangulation makes a fixed number whatever the size."""
    from nhstab.geometry import convex_parts, polygon_area

    for ring in (star(2_000), comb(500)):
        parts = convex_parts(ring)
        assert python_calls(convex_parts, ring) < 500
        assert all(polygon_area(t) > 0 for t in parts)                 # counter-clockwise, none flat
        assert math.isclose(sum(polygon_area(t) for t in parts), abs(polygon_area(ring)), rel_tol=1e-9)
    with pytest.raises(InputError, match="simple"):
        convex_parts(np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]))     # a bowtie


def test_the_raster_fill_agrees_with_point_in_polygon_and_its_work_is_the_crossings():
    """A point-in-polygon test per cell costs cells x vertices at worst (the comb's edges span every
    row); the scanline fill toggles cells per crossing, at most vertices x rows."""
    from matplotlib.path import Path as MplPath
    from nhstab.maps import raster

    rng = np.random.default_rng(3)
    xs, ys = np.linspace(0, 10, 211), np.linspace(0, 10, 173)
    X, Y = np.meshgrid(xs, ys)
    for ring in [rng.uniform(-1, 11, (k, 2)) for k in (3, 7, 30, 60)] + [comb(40) + [1.0, 0.3], star(300) - [1, 0]]:
        want = MplPath(ring).contains_points(np.column_stack([X.ravel(), Y.ravel()])).reshape(X.shape)
        assert np.array_equal(raster.ring_cells(ring, xs, ys), want)
    # a ring drawn out and back encloses nothing
    assert not raster.ring_cells(np.array([[1.0, 1.0], [9.0, 8.0], [5.0, 2.0], [9.0, 8.0]]), xs, ys).any()
    # the work: the edges are taken in chunks of crossings; a comb of 2,000 teeth over 173 rows is
    # 2,000 x 2 x 173 crossings, so a handful of chunks, never a cell-by-vertex product
    big = comb(2_000, x0=0.5, y0=0.5, width=4.0, reach=4.0, height=9.0)
    seen = []
    real = np.bincount

    def counting(idx, minlength=0):
        seen.append(len(idx))
        return real(idx, minlength=minlength)

    mp = pytest.MonkeyPatch()
    mp.setattr(raster.np, "bincount", counting)
    try:
        cells = raster.ring_cells(big, xs, ys)
    finally:
        mp.undo()
    rows_crossed = 2 * 2_000 * len(ys)
    assert sum(seen) <= rows_crossed and len(seen) <= rows_crossed // raster.CROSSINGS_PER_CHUNK + 2
    cell = (xs[1] - xs[0]) * (ys[1] - ys[0])
    import shapely

    assert abs(cells.sum() * cell - shapely.Polygon(big).intersection(shapely.box(0, 0, 10, 10)).area) < 0.05 * 100


# ---- batches ----------------------------------------------------------------------------------------

def test_a_batch_grid_beyond_the_trial_bound_is_refused_before_any_cell_is_made(tmp_path, monkeypatch):
    """Four grid keys of 100 values each are 100,000,000 cells: they were expanded (minutes, then a
    MemoryError) before the bound was checked. The count is now the product of the sizes."""
    from nhstab.batch import config as bc

    def no_cells(self):
        raise AssertionError("cells were expanded before the trial bound was checked")

    monkeypatch.setattr(bc.BatchConfig, "cells", no_cells)
    b = tmp_path / "batch.yaml"
    values = "[" + ", ".join(f"{0.5 + i / 100:.2f}" for i in range(40)) + "]"
    b.write_text(f"root_seed: 1\ntrials: 1\nmaps: [{{path: {M}}}]\ncontrollers: [gramian, tvlqr]\n"
                 f"grid:\n  alpha: {values}\n  delta: {values}\n  gamma: {values}\n  noise: {values}\n")
    one_line(invoke("batch", b, "--out", tmp_path / "o"), 2, "'trials'", "1,000,000",
             f"{(40 ** 3 + 1) * 40:,} cells x 1 = {(40 ** 3 + 1) * 40:,}")
    assert not (tmp_path / "o").exists()


def test_the_cell_count_from_sizes_is_the_number_of_cells(tmp_path):
    from nhstab.batch.config import load_batch_config

    b = tmp_path / "batch.yaml"
    b.write_text(f"root_seed: 1\ntrials: 2\nmaps: [{{path: {M}}}]\ncontrollers: [gramian, tvlqr]\n"
                 "robots: [unicycle, {model: unicycle, name: slow, max_speed: 0.5}]\n"
                 "grid:\n  alpha: [0.1, 0.2, 0.3]\n  gamma: [0.5, 1.0]\n  window: [future, past]\n"
                 "  noise: [0.5, 1.0]\n")
    cfg = load_batch_config(b)
    assert cfg.cell_count() == len(cfg.cells()) == 2 * (3 * 2 * 2 + 1) * 2


def footprint_file(path: Path, body: str, model: str = "unicycle") -> Path:
    path.write_text(f"model: {model}\n{body}\n")
    return path


def test_a_footprint_is_checked_without_a_python_loop_over_its_edge_pairs():
    """The footprint's simplicity test compared every pair of edges in Python: 9 s at 2,000 points and
    minutes at the 10,000 allowed. GEOS's test makes a fixed number of Python calls."""
    from nhstab.robot import parse_footprint

    for k in (400, 2_000):
        spec = {"polygon": (star(k, 0.0, 0.0) / 10).tolist()}
        fp = parse_footprint(spec)
        assert len(fp.vertices) == k
        assert python_calls(parse_footprint, spec) < 40 * k        # per point: its numbers; no pair loop


@pytest.mark.parametrize("points,reason", [
    ([[0, 0], [1, 1], [1, 0], [0, 1]], "simple polygon (its edges must not cross or touch each other)"),   # a bowtie
    ([[0, 0], [2, 0], [2, 2], [1, -1], [0, 2]], "simple polygon"),             # an edge through another
    ([[0, 0], [1, 0], [3, 0], [2, 0]], "not all points on a line"),
    ([[0, 0], [1, 1e-13], [2, 0]], "not all points on a line"),
])
def test_a_footprint_is_refused_for_the_right_reason(points, reason):
    from nhstab.robot import parse_footprint

    with pytest.raises(InputError, match="'footprint.polygon'") as err:
        parse_footprint({"polygon": points})
    assert reason in str(err.value)


@pytest.mark.parametrize("body,key", [
    ("footprint: {rectangle: {length: 1.0e+300, width: 1.0}}", "robot.footprint.rectangle.length"),
    ("footprint: {rectangle: {length: 2.0, width: 2.0e+6}}", "robot.footprint.rectangle.width"),
    ("footprint: {polygon: [[0, 0], [1.0e+160, 0], [0, 1]]}", "robot.footprint.polygon[1][0]"),
    ("footprint: {polygon: [[0, 0], [1, 0], [0, -1.0e+7]]}", "robot.footprint.polygon[2][1]"),
    ("footprint: {radius: .inf}", "robot.footprint.radius"),
    ("margin: 1.0e+300", "robot.margin"),
])
def test_a_robots_lengths_are_bounded_like_coordinates(tmp_path, body, key):
    out = tmp_path / "o"
    line = one_line(invoke("plan", M, "--robot-config", footprint_file(tmp_path / "r.yaml", body), "--out", out), 2, key)
    assert "1e+06" in line and not out.exists()


def test_every_way_a_robot_is_read_bounds_its_size(tmp_path):
    m = tmp_path / "m.yaml"
    m.write_text("name: r\nbounds: [0, 0, 12, 9]\nstart: [1, 1, 0]\ngoal: [10, 8, 0]\n"
                 "robot: {model: rwd_car, wheelbase: 1.0e+300}\n")
    one_line(invoke("map", "info", m), 2, "robot.wheelbase", "1e+06")
    m.write_text("name: r\nbounds: [0, 0, 12, 9]\nstart: [1, 1, 0]\ngoal: [10, 8, 0]\n"
                 "robot: {model: unicycle, footprint: {rectangle: {length: 1.0e+300, width: 1}}}\n")
    one_line(invoke("plan", m, "--out", tmp_path / "o"), 2, "robot.footprint.rectangle.length")
    b = tmp_path / "batch.yaml"
    b.write_text(f"root_seed: 1\ntrials: 1\nmaps: [{{path: {M}}}]\n"
                 "robots: [{model: car_trailer, hitch_lengths: [3.0, 1.0e+200]}]\n")
    one_line(invoke("batch", b, "--out", tmp_path / "o"), 2, "robots[0].hitch_lengths[1]", "1e+06")
    from nhstab.geometry import Footprint
    from nhstab.robot import make_robot

    with pytest.raises(InputError, match="footprint.radius"):
        Footprint.disc(1e300)
    with pytest.raises(InputError, match="footprint.vertices"):
        Footprint.polygon([[0, 0], [1e160, 0], [0, 1]])
    with pytest.raises(InputError, match="footprint"):
        Footprint.rectangle(1e300, 1.0)
    with pytest.raises(InputError, match="robot.footprint.radius"):
        make_robot("unicycle", footprint={"radius": 2e6})
    assert not (tmp_path / "o").exists()


# ---- turning radius and steering ------------------------------------------------------------------

@pytest.mark.parametrize("args", [("--robot", "fwd_car", "--turning-radius", "1e6"),
                                  ("--turning-radius", "1e300"), ("--robot", "rwd_car", "--turning-radius", "16")])
def test_a_turning_radius_beyond_the_maps_diagonal_is_refused(tmp_path, args):
    """1e9 allocated a 234 GiB array of arc samples, 1e300 asked numpy for more than it can index, and
    1e6 took several times the planning budget; the room is 15 m across."""
    out = tmp_path / "o"
    one_line(invoke("plan", M, *args, "--out", out), 2, "'--turning-radius'", "the map's diagonal, 15 m")
    assert not out.exists()


def test_a_robot_files_turning_radius_is_bounded(tmp_path):
    r = footprint_file(tmp_path / "r.yaml", "turning_radius: 1.0e+300", "rwd_car")
    one_line(invoke("plan", M, "--robot-config", r, "--out", tmp_path / "o"), 2, "robot.turning_radius", "1e+06")
    r = footprint_file(tmp_path / "r.yaml", "turning_radius: 100.0", "rwd_car")
    one_line(invoke("plan", M, "--robot-config", r, "--out", tmp_path / "o"), 2, "robot.turning_radius'", "diagonal")
    from nhstab.maps import load_map
    from nhstab.planning import PathOptions, plan
    from nhstab.robot import default_robot

    m = load_map(M)
    with pytest.raises(InputError, match="'turning_radius' must be at most the map's diagonal"):
        plan(m, default_robot("fwd_car"), m.start.as_array(), m.goal.as_array(), PathOptions(turning_radius=1e7))


def test_a_batch_refuses_a_turning_radius_beyond_a_maps_diagonal_before_any_trial(tmp_path):
    """Every trial's plan would refuse it: the batch refuses it once, at load, naming the key."""
    b = tmp_path / "batch.yaml"
    b.write_text(f"root_seed: 1\ntrials: 1\nmaps: [{{path: {M}}}]\n"
                 "robots: [unicycle, {model: unicycle, name: wide, turning_radius: 100.0}]\n")
    one_line(invoke("batch", b, "--out", tmp_path / "o"), 2, "'robots[1].turning_radius'", "diagonal, 15 m",
             "cluttered-room")
    b.write_text(f"root_seed: 1\ntrials: 1\nmaps: [{{path: {M}}}]\nrun: {{planning: {{turning_radius: 20.0}}}}\n")
    one_line(invoke("batch", b, "--out", tmp_path / "o"), 2, "'run.planning.turning_radius'", "diagonal")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("model,steer", [("fwd_car", 1.5707963267948966), ("rwd_car", 1.5707963267948963),
                                         ("car_trailer", math.pi / 2 - 1e-6), ("fwd_car", 2.0)])
def test_a_steering_limit_at_pi_over_2_is_refused(tmp_path, model, steer):
    """max_steer at pi/2 makes the turning radius wheelbase / tan(max_steer) about 1e-16 m: the local
    paths' legs did not meet (a RuntimeError traceback). fwd_car took any angle, even beyond pi/2."""
    r = footprint_file(tmp_path / "r.yaml", f"max_steer: {steer!r}", model)
    # at or beyond pi/2: not an angle below pi/2; just below it: a turning radius under 1 mm
    why = "below pi/2" if steer >= math.pi / 2 else "atan(wheelbase / 0.001 m)"
    one_line(invoke("plan", "example:parking_lot", "--robot-config", r, "--out", tmp_path / "o"), 2,
             "robot.max_steer", why)
    from nhstab.models import make_model

    assert make_model(model, max_steer=1.5).max_steer == 1.5            # steep, still a car
    with pytest.raises(InputError, match="max_steer"):
        make_model(model, max_steer=steer)


# ---- probabilities and noise --------------------------------------------------------------------------

@pytest.mark.parametrize("p", ["0.9999999999999999", "0.99999999999", "1.0", "nan", "0"])
def test_a_tube_probability_near_1_is_refused_everywhere(tmp_path, p):
    """p = 1 - 1e-16 made the linear tube's quantile q = 1 - (1 - p) / 2 round to 1: log(0), a "math domain
    error" traceback."""
    out = tmp_path / "o"
    one_line(invoke("plan", M, "--probability", p, "--tube", "linear", "--out", out), 2, "'--probability'",
             "(0, 0.999999999]")
    one_line(invoke("run", M, "--probability", p, "--out", out), 2, "'--probability'", "0.999999999")
    cfg = tmp_path / "run.yaml"
    cfg.write_text(f"map: {M}\ntube: {{kind: linear, probability: {p}}}\n")
    one_line(invoke("run", "--config", cfg, "--out", out), 2, "tube.probability")
    assert not out.exists()


def test_the_linear_tube_refuses_a_probability_its_quantile_cannot_honour():
    from nhstab import limits
    from nhstab.tubes import predict_tube, rollouts_needed

    with pytest.raises(InputError, match="'probability' must be a number in"):
        predict_tube(None, None, None, probability=1 - 1e-16, kind="linear")
    with pytest.raises(InputError, match="'probability'"):
        rollouts_needed(1 - 1e-12, 0.5)
    q = 1.0 - (1.0 - limits.MAX_PROBABILITY) / 2.0
    assert q < 1.0 and math.isfinite(-2.0 * math.log(1.0 - q))


@pytest.mark.parametrize("value", ["1e300", "1e4", "inf", "nan", "-1"])
def test_a_noise_scale_beyond_its_bound_is_refused(tmp_path, value):
    """--noise 1e300 gave "cannot convert float NaN to integer" in plan and, in run, numpy's overflow
    warnings and a robot 6e301 m away reported as a missed goal."""
    out = tmp_path / "o"
    one_line(invoke("plan", M, "--robot", "fwd_car", "--noise", value, "--out", out), 2, "'--noise'", "[0, 1000]")
    one_line(invoke("run", M, "--noise", value, "--out", out), 2, "'--noise'", "[0, 1000]")
    assert not out.exists()


@pytest.mark.parametrize("noise,key", [("{scale: 1.0e+300}", "noise.scale"), ("{sensor: {x: 1.0e+300}}", "noise.sensor.x"),
                                       ("{initial: {theta: 2.0e+6}}", "noise.initial.theta"),
                                       ("{impulses: [{time: 1.0, y: -1.0e+300}]}", "noise.impulses[0].y")])
def test_noise_levels_in_configs_are_bounded(tmp_path, noise, key):
    cfg = tmp_path / "run.yaml"
    cfg.write_text(f"map: {M}\nnoise: {noise}\n")
    one_line(invoke("run", "--config", cfg, "--out", tmp_path / "o"), 2, key)
    b = tmp_path / "batch.yaml"
    b.write_text(f"root_seed: 1\ntrials: 1\nmaps: [{{path: {M}}}]\nrun: {{noise: {noise}}}\n")
    one_line(invoke("batch", b, "--out", tmp_path / "o"), 2, key)
    b.write_text(f"root_seed: 1\ntrials: 1\nmaps: [{{path: {M}}}]\ngrid: {{noise: [1.0, 1.0e+300]}}\n")
    one_line(invoke("batch", b, "--out", tmp_path / "o"), 2, "grid.noise[1]", "[0, 1000]")
    assert not (tmp_path / "o").exists()


# ---- the paper's nominal ---------------------------------------------------------------------------------

@pytest.mark.parametrize("delta", ["1e6", "1e300", "100.001"])
def test_the_papers_window_is_bounded_before_its_nominal_is_sampled(tmp_path, delta):
    """--delta 1e6 asked for 5e8 samples (a 3.7 GiB MemoryError), 1e300 for more than numpy can index."""
    out = tmp_path / "p"
    one_line(invoke("paper", "--case", "heisenberg-line", "--case", "hilare-circle", "--delta", delta, "--out", out),
             2, "'--delta'", "at most 100 s")
    assert not out.exists()


def test_the_papers_nominal_is_held_to_the_sample_bound():
    from nhstab.limits import MAX_NOMINAL_SAMPLES
    from nhstab.paper import CASES, GRID_HZ, nominal_samples

    case = CASES["remark2-line"]                  # starts at t = delta: the window counts twice
    assert nominal_samples(case, GRID_HZ, 100.0) == round((2 * 100.0 + case.duration_s) * GRID_HZ) + 1
    hz = (MAX_NOMINAL_SAMPLES - 1) / (2 * 50.0 + case.duration_s)        # a grid whose nominal just fits
    assert nominal_samples(case, hz * 0.999, 50.0) <= MAX_NOMINAL_SAMPLES
    with pytest.raises(InputError, match="2,000,000 samples"):
        nominal_samples(case, hz * 1.001, 50.0)
