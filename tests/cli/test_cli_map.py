"""nhstab map show / info on the bundled maps."""

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from nhstab.cli.main import cli

MAPS = Path(__file__).parents[2] / "maps"


@pytest.fixture
def runner():
    return CliRunner()


@pytest.mark.parametrize("rel,extra", [("nav2/depot.yaml", []), ("movingai/64room_000.map", ["--cell-size", "0.5"]),
                                       ("bench-mr/polygon_mazes/parking1.svg", []), ("ours/parking_lot.yaml", [])])
def test_info_json(runner, rel, extra):
    res = runner.invoke(cli, ["map", "info", str(MAPS / rel), "--json", *extra])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert 0.0 < info["free_fraction"] < 1.0
    assert info["size_m"][0] > 0 and info["size_m"][1] > 0


def test_info_depot_matches_source_counts(runner):
    """SOURCE.md: depot is 604 x 307 cells at 0.05 m, 3.2 % occupied."""
    info = json.loads(runner.invoke(cli, ["map", "info", str(MAPS / "nav2/depot.yaml"), "--json"]).output)
    (grid,) = info["grids"]
    assert grid["cells"] == [307, 604] and grid["resolution_m"] == 0.05
    assert info["free_fraction"] == pytest.approx(0.968, abs=0.002)


def test_info_reports_start_goal_clearance(runner):
    info = json.loads(runner.invoke(cli, ["map", "info", str(MAPS / "ours/parking_lot.yaml"), "--json"]).output)
    assert info["start_clearance_m"] > 0 and info["goal_clearance_m"] > 0
    assert info["unknown_obstacles"] >= 1


def test_show_writes_png(runner, tmp_path):
    out = tmp_path / "lot.png"
    res = runner.invoke(cli, ["map", "show", str(MAPS / "ours/parking_lot.yaml"), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000


def _one_line(res, *needles):
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in res.output, res.output
    for n in needles:
        assert n in lines[0], lines[0]


def test_show_refuses_start_in_collision(runner, tmp_path):
    # a car parked on top of the first parked car of the lot
    res = runner.invoke(cli, ["map", "show", str(MAPS / "ours/parking_lot.yaml"), "--start", "8.0,3.5,1.57",
                              "--out", str(tmp_path / "x.png")])
    _one_line(res, "start", "overlaps")
    assert not (tmp_path / "x.png").exists()


def test_show_refuses_pose_outside_bounds_and_bad_pose(runner, tmp_path):
    _one_line(runner.invoke(cli, ["map", "show", str(MAPS / "ours/parking_lot.yaml"), "--goal", "500,3,0",
                                  "--out", str(tmp_path / "x.png")]), "goal", "bounds")
    _one_line(runner.invoke(cli, ["map", "show", str(MAPS / "ours/parking_lot.yaml"), "--goal", "1,two,0",
                                  "--out", str(tmp_path / "x.png")]), "--goal", "x,y,theta")


def test_bad_map_files(runner, tmp_path):
    _one_line(runner.invoke(cli, ["map", "info", str(tmp_path / "nope.yaml")]), "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nbounds: [0, 0, 10, 10]\nobstacles:\n  - polygon: [[0, 0], [1, 1]]\n")
    _one_line(runner.invoke(cli, ["map", "info", str(bad)]), "bad.yaml", "polygon")
    ros = tmp_path / "r.yaml"
    ros.write_text("image: r.pgm\nresolution: -0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n")
    _one_line(runner.invoke(cli, ["map", "info", str(ros)]), "r.yaml", "resolution")


def test_every_bundled_map_loads_builds_and_draws(tmp_path):
    """Every map file copied from the shared research folder (and ours) loads, becomes a collision
    world, and `map info` summarises it."""
    from nhstab.collision import CollisionWorld
    from nhstab.maps import load_map

    files = sorted(p for p in MAPS.rglob("*") if p.suffix in (".yaml", ".map", ".svg")
                   and "configs" not in p.relative_to(MAPS).parts)          # the bundled run and batch configs
    assert len(files) >= 15
    for path in files:
        m = load_map(path)
        world = CollisionWorld.from_map(m)
        assert world.n_objects >= 4, path            # at least the four boundary walls
        res = CliRunner().invoke(cli, ["map", "info", str(path), "--json"])
        assert res.exit_code == 0, (path, res.output)


ROS_OK = "image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n"


@pytest.mark.parametrize("files,needles", [
    ({"m.yaml": ROS_OK, "m.pgm": b"P5\n4 4\n255\n\x00\x00"}, ["m.pgm"]),                          # truncated image
    ({"m.yaml": ROS_OK, "m.pgm": b"GIF89a not an image"}, ["m.pgm"]),                              # unreadable image
    ({"m.yaml": ROS_OK + "colour: red\n", "m.pgm": b"P5\n1 1\n255\n\xff"}, ["m.yaml", "colour"]),  # unknown key
    ({"m.yaml": "bounds: [0, 0, 10, .nan]\n"}, ["m.yaml", "bounds"]),                             # NaN
    ({"m.yaml": "bounds: [0, 0, 10, 10]\nstart: [12, 5, 0]\n"}, ["m.yaml", "start"]),              # start outside
    ({"m.yaml": "bounds: [0, 0, 10, 10]\nobstacles:\n  - box: {center: [5, 5], size: [2, 2]}\n"
                "goal: [5, 5, 0]\n"}, ["m.yaml", "goal"]),                                         # goal inside
    ({"m.yaml": "bounds: [0, 0, 10, 10]\nobstacles:\n  - box: {center: [5, 5], size: [2, 2]}\n"
                "start: [3.8, 5, 0]\nrobot: {model: unicycle}\n"}, ["start", "overlaps"]),         # footprint hits
])
def test_bad_maps_one_line_exit_2(runner, tmp_path, files, needles):
    for name, content in files.items():
        (tmp_path / name).write_bytes(content if isinstance(content, bytes) else content.encode())
    for cmd in (["map", "info", str(tmp_path / "m.yaml")], ["map", "show", str(tmp_path / "m.yaml"),
                                                           "--out", str(tmp_path / "m.png")]):
        _one_line(runner.invoke(cli, cmd), *needles)
    assert not (tmp_path / "m.png").exists()
