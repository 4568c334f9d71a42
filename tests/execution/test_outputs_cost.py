"""The cheap forms of a plan's outputs against the straightforward computations
they replace: the CSV writers, the feasibility residual's multiple shooting and its scan, the map
raster and the palette PNG."""

import csv
import io
from pathlib import Path

import numpy as np
import pytest
from nhstab.maps import load_map
from nhstab.nominal import Nominal, affine_scan
from nhstab.planning import PathOptions, plan
from nhstab.robot import default_robot
from nhstab.trajectory_io import column_names, float_rows, read_trajectory, write_trajectory
from PIL import Image
from scipy.integrate import solve_ivp

MAPS = Path(__file__).parents[2] / "maps"


@pytest.fixture(scope="module")
def planned():
    """A real unicycle plan: Reeds-Shepp path, cusps, trapezoidal speed (u0 jumps in curvature)."""
    m = load_map(MAPS / "ours/cluttered_room.yaml")
    rob = default_robot("unicycle")
    r = plan(m, rob, m.start.as_array(), m.goal.as_array(), PathOptions(seed=1, time_limit_s=5.0))
    assert r.ok, r.message
    return m, rob, r


def _csv_by_rows(header, rows) -> str:
    """The writer this replaces: csv.writer, one row at a time, each float as repr(float(v))."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for row in rows:
        w.writerow([repr(float(v)) for v in row])
    return buf.getvalue()


def test_trajectory_csv_is_byte_identical_to_the_row_by_row_writer(planned, tmp_path):
    _, _, r = planned
    nom = r.nominal
    write_trajectory(tmp_path / "t.csv", nom)
    expected = _csv_by_rows(column_names(nom.model), np.column_stack([nom.t, nom.x, nom.u]))
    assert (tmp_path / "t.csv").read_text() == expected
    back = read_trajectory(tmp_path / "t.csv", nom.model)          # and it round-trips exactly
    assert np.array_equal(back.t, nom.t) and np.array_equal(back.x, nom.x) and np.array_equal(back.u, nom.u)


def test_float_rows_on_awkward_values():
    a = np.array([[0.0, -0.0, 1e-300, -2.5e300], [np.inf, -np.inf, 1.0, 0.1], [2.0, 1 / 3, -1e-5, 123456789.0]])
    expected = _csv_by_rows(["a", "b", "c", "d"], a).split("\n", 1)[1]
    assert float_rows(a) == expected
    assert float_rows(np.array([[np.nan, 1.5]])) == "nan,1.5\n"
    assert float_rows(np.zeros((0, 3))) == ""


def test_run_csv_is_byte_identical_to_the_row_by_row_writer():
    """The run's CSV (floats, an integer plan id and a mode name per row) against the per-row writer."""
    from types import SimpleNamespace

    from nhstab.execution.outputs import csv_columns, trajectory_csv
    from nhstab.execution.runner import MODES
    from nhstab.models import make_model

    rng = np.random.default_rng(13)
    n = 500
    log = {"t": np.arange(n) * 0.02, "plan_id": rng.integers(0, 3, n), "mode": rng.integers(0, 3, n),
           "x": rng.normal(size=(n, 3)) * 50, "x0": rng.normal(size=(n, 3)), "y": rng.normal(size=(n, 3)),
           "u": rng.normal(size=(n, 2)), "u0": rng.normal(size=(n, 2))}
    result = SimpleNamespace(log=log, model=make_model("unicycle"))
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(csv_columns(result))
    for k in range(n):
        nums = np.concatenate([log["x"][k], log["x0"][k], log["y"][k], log["u"][k], log["u0"][k]])
        w.writerow([repr(float(log["t"][k])), int(log["plan_id"][k]), MODES[log["mode"][k]],
                    *(repr(float(v)) for v in nums)])
    assert trajectory_csv(result) == buf.getvalue()


def test_affine_scan_matches_the_sequential_recurrence():
    rng = np.random.default_rng(7)
    for N in (1, 2, 3, 17, 100, 1001):
        P = np.eye(3) + 0.05 * rng.normal(size=(N, 3, 3))
        D = rng.normal(size=(N, 3))
        e, ref = np.zeros(3), np.empty((N, 3))
        for k in range(N):
            e = P[k] @ e + D[k]
            ref[k] = e
        assert np.allclose(affine_scan(P, D), ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_residual_of_a_real_nominal_agrees_with_one_tight_adaptive_integration(planned):
    """The nominal integrated once from x0(0) under u0 by scipy's DOP853 (rtol = atol = 1e-12, steps of
    at most half the grid step, so that no curvature change is stepped over): the largest deviation
    at the grid points, the straightforward computation the multiple shooting replaces. The nominal
    is exact by construction (closed-form arcs), so both are integration error: within 1e-8 m of
    each other. With a smooth bump added to x0 (zero at the start), the exact residual is the bump's
    largest value at the grid points, which the multiple shooting finds to 1e-6 relative."""
    _, rob, r = planned
    nom = r.nominal
    dt = float(nom.t[1] - nom.t[0])

    def straightforward(n):
        sol = solve_ivp(lambda t, x: rob.model.rhs(x, n._u_func(np.array([t]))[0]), (n.t[0], n.t[-1]), n.x[0],
                        method="DOP853", rtol=1e-12, atol=1e-12, t_eval=n.t, max_step=dt / 2)
        return float(np.abs(sol.y.T - n.x).max())

    fast, slow = nom.feasibility_residual(), straightforward(nom)
    assert fast < 1e-8 and abs(fast - slow) < 1e-8
    assert nom.u_breaks is not None and len(nom.u_breaks) > 2          # the path's curvature changes
    blind = Nominal.from_functions(rob.model, nom._x_func, nom._u_func, nom.t)   # no breaks: refinement
    assert blind.u_breaks is None and abs(blind.feasibility_residual() - fast) < 1e-9
    T = nom.t[-1]

    def bumped(t):
        x = np.array(nom._x_func(t), dtype=float)
        x[..., 0] += 1e-4 * np.sin(np.pi * np.asarray(t) / T) ** 2
        return x

    off = Nominal.from_functions(rob.model, bumped, nom._u_func, nom.t)
    bump = 1e-4 * np.sin(np.pi * nom.t / T) ** 2
    assert off.feasibility_residual() == pytest.approx(bump.max(), rel=1e-6)


def test_a_unicycle_nominal_knows_where_its_input_is_not_smooth(planned, monkeypatch):
    """PathTiming.breaks: each run's progress inverted at the breaks gives back their arc lengths
    (1e-9 m), u0 jumps or kinks there, and with them the residual needs at most one refinement
    level on a real nominal (it needed about ten without)."""
    import nhstab.nominal as nominal_module
    from nhstab.planning.timing import PathTiming

    _, rob, r = planned
    nom = r.nominal
    timing = PathTiming(r.path, 1.0, 0.5)
    for run in timing.runs:
        s = np.linspace(0.0, run.length, 57)
        np.testing.assert_allclose(run.progress(run.time_at(s))[0], s, atol=1e-9)
    b = nom.u_breaks[(nom.u_breaks > nom.t[0] + 1e-6) & (nom.u_breaks < nom.t[-1] - 1e-6)]
    assert len(b) >= 2
    # at every break u0 jumps or its slope does: compare one-sided differences
    eps = 1e-6
    left = (nom._u_func(b - eps) - nom._u_func(b - 2 * eps)) / eps
    right = (nom._u_func(b + 2 * eps) - nom._u_func(b + eps)) / eps
    jump = np.abs(nom._u_func(b + eps) - nom._u_func(b - eps)).max(axis=1)
    assert np.all((jump > 1e-4) | (np.abs(right - left).max(axis=1) > 1e-3))
    levels = []
    step = nominal_module._Shooting.interval
    monkeypatch.setattr(nominal_module._Shooting, "interval",
                        lambda self, *a, **k: levels.append(len(a[0])) or step(self, *a, **k))
    nom.feasibility_residual()
    assert len(levels) <= 2


def test_map_raster_is_pixel_identical_to_imshow():
    """GridRaster draws what imshow(interpolation="nearest") draws, pixel for pixel, on a real map."""
    from nhstab.records import _figure_pixels
    from nhstab.report import subplots
    from nhstab.report.maps import GridRaster, grid_image

    m = load_map(MAPS / "nav2/depot.yaml")
    g = m.grids[0]
    H, W = g.shape
    ox, oy, _ = g.origin
    extent = (ox, ox + W * g.resolution, oy, oy + H * g.resolution)
    xmin, ymin, xmax, ymax = m.bounds
    pixels = []
    for use_imshow in (True, False):
        fig, ax = subplots(figsize=(5, 4))
        if use_imshow:
            ax.imshow(grid_image(g), origin="lower", interpolation="nearest", extent=extent)
        else:
            ax.add_artist(GridRaster(grid_image(g), extent))
        ax.set_xlim(xmin - 2.3, xmax + 1.1)               # part of the map outside the view on one side
        ax.set_ylim(ymin + 1.7, ymax + 2.0)
        ax.set_aspect("equal")
        pixels.append(np.asarray(_figure_pixels(fig, 110)))
    assert pixels[0].shape == pixels[1].shape
    assert np.array_equal(pixels[0], pixels[1])


def test_plan_png_is_a_palette_image_within_16_levels_of_the_drawing(planned, tmp_path):
    from nhstab.planning import pose_columns
    from nhstab.records import _figure_pixels, save_figure
    from nhstab.report.plans import plan_figure

    m, rob, r = planned
    nom = r.nominal
    fig = plan_figure(m, nom.x[:, pose_columns(rob.model)], np.sign(nom.u[:, 0]), rob.footprint,
                      nom.x[0], nom.x[-1], title="a plan\nsecond line")
    drawn = np.asarray(_figure_pixels(fig, 110)).astype(int)
    save_figure(fig, tmp_path / "p.png", fast_palette=True)           # as write_plan stores plan.png
    with Image.open(tmp_path / "p.png") as im:
        assert im.mode == "P"
        stored = np.asarray(im.convert("RGB")).astype(int)
    assert stored.shape == drawn.shape
    err = np.abs(stored - drawn)
    assert err.max() <= 16 and err.mean() < 2.0


def test_a_figure_with_a_colour_map_keeps_median_cut_quality(tmp_path):
    """By default the palette is median cut's, which bands a smooth colour map less than the fast
    octree: mean error under 1 level here, against more for the octree."""
    from nhstab.records import _figure_pixels, save_figure
    from nhstab.report import subplots

    fig, ax = subplots(figsize=(5, 4))
    x = np.linspace(0, 1, 300)
    ax.imshow(np.sin(8 * x[None]) * np.cos(5 * x[:, None]), cmap="viridis")
    drawn = np.asarray(_figure_pixels(fig, 110)).astype(int)
    errors = []
    for fast in (False, True):
        save_figure(fig, tmp_path / "g.png", fast_palette=fast)
        with Image.open(tmp_path / "g.png") as im:
            errors.append(np.abs(np.asarray(im.convert("RGB")).astype(int) - drawn).mean())
    assert errors[0] < 1.0 and errors[0] < errors[1]


def test_a_figure_is_stored_at_zlib_level_9(tmp_path):
    """save_figure deflates at PIL's best (optimize): its PNG, decoded and stored again that way, is the
    same bytes, and smaller than the same palette image at PIL's default level."""
    import io

    from nhstab.records import save_figure
    from nhstab.report import subplots

    fig, ax = subplots(figsize=(5, 4))
    ax.plot(np.linspace(0, 1, 50), np.sin(np.linspace(0, 6, 50)), label="a line")
    ax.legend()
    data = save_figure(fig, tmp_path / "f.png").read_bytes()
    with Image.open(io.BytesIO(data)) as im:
        im.load()
        again, default = io.BytesIO(), io.BytesIO()
        im.save(again, format="PNG", optimize=True)
        im.save(default, format="PNG")
    assert again.getvalue() == data and len(data) < len(default.getvalue())
