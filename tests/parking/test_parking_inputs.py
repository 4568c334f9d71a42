"""Real data is accepted: polygons with repeated consecutive vertices or
zero-length edges in Bench-MR SVG worlds are cleaned and noted, not refused; poses of the wrong
length given to the collision API raise an InputError naming the argument."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from nhstab.cli.main import cli
from nhstab.collision import CollisionWorld, check_poses
from nhstab.errors import InputError
from nhstab.maps import load_map
from nhstab.maps.base import Map, Polygon
from nhstab.robot import default_robot

SCALE = 22.0            # Bench-MR: world = (x, -y) / 22


def _svg(tmp_path, *paths) -> str:
    body = "".join(f'<path id="p{k}" d="{d}"/>' for k, d in enumerate(paths))
    f = tmp_path / "world.svg"
    f.write_text(f'<svg xmlns="http://www.w3.org/2000/svg">{body}</svg>')
    return f


def test_svg_repeated_vertices_and_zero_length_edges_are_dropped_and_noted(tmp_path):
    clean = "M 0,0 L 220,0 L 220,-110 L 0,-110 Z"
    messy = ("M 0,0 L 220,0 L 220,0 l 0,0 L 220,-110 L 0,-110 L 0,-110 L 0,0 L 0,0 Z")   # 3 repeats + closing
    a = load_map(_svg(tmp_path, clean, "M 440,0 L 660,0 L 660,-110 Z"))
    (tmp_path / "b").mkdir()
    b = load_map(_svg(tmp_path / "b", messy, "M 440,0 L 660,0 L 660,-110 Z"))
    assert len(b.obstacles) == 2
    np.testing.assert_allclose(b.obstacles[0].vertices, a.obstacles[0].vertices, atol=0)
    assert b.obstacles[0].area == pytest.approx(10.0 * 5.0)
    assert a.meta["notes"] == []
    (note,) = b.meta["notes"]
    assert "dropped 4 repeated consecutive vertex(es)" in note and "1 of 2 paths (#0)" in note
    res = CliRunner().invoke(cli, ["map", "info", str(tmp_path / "b" / "world.svg")])
    assert res.exit_code == 0 and "note" in res.output and "repeated consecutive" in res.output


def test_svg_near_repeats_within_a_nanometre_count_as_repeats(tmp_path):
    eps = 1e-11 * SCALE            # 1e-11 world units
    m = load_map(_svg(tmp_path, f"M 0,0 L 220,0 L {220 + eps},0 L 220,-110 L 0,-110 Z"))
    assert len(m.obstacles[0].vertices) == 4
    assert m.meta["notes"]


def test_svg_that_collapses_is_still_refused_with_one_line(tmp_path):
    from nhstab.maps.base import MapError

    with pytest.raises(MapError, match="p0|path #0"):
        load_map(_svg(tmp_path, "M 0,0 L 220,0 L 220,0 L 0,0 Z"))


def test_the_bundled_bench_mr_worlds_note_their_repeated_closing_vertices():
    from nhstab.examples import example_path

    m = load_map(example_path("parking1"))
    (note,) = m.meta["notes"]
    assert "3 of 13 paths" in note
    for poly in m.obstacles:
        d = np.abs(np.diff(np.vstack([poly.vertices, poly.vertices[:1]]), axis=0)).max(axis=1)
        assert d.min() > 1e-9           # no zero-length edge left


@pytest.fixture(scope="module")
def world():
    m = Map("box", (0.0, 0.0, 20.0, 10.0), obstacles=(Polygon(np.array([[8.0, 4.0], [12.0, 4.0], [12.0, 6.0],
                                                                             [8.0, 6.0]])),))
    return m, CollisionWorld.from_map(m)


BAD_POSES = {"two numbers": [1.0, 2.0], "a car's full state": [1.0, 2.0, 0.0, 0.1],
             "five numbers": [1.0, 2.0, 0.0, 0.0, 0.0], "NaN": [math.nan, 2.0, 0.0], "None": None,
             "text": "1,2,0", "a (1, 2) array": [[1.0, 2.0]], "nothing": []}


@pytest.mark.parametrize("bad", list(BAD_POSES))
@pytest.mark.parametrize("query", ["in_collision", "distance", "clearance", "is_free"])
def test_single_pose_queries_name_the_pose(world, query, bad):
    _, w = world
    fp = default_robot("rwd_car").footprint
    with pytest.raises(InputError, match="'pose' must be a pose of three finite numbers"):
        getattr(w, query)(BAD_POSES[bad], fp)
    assert getattr(w, query)((3.0, 2.0, 0.0), fp) is not None        # a good pose still works


@pytest.mark.parametrize("bad", ["two numbers", "a car's full state", "NaN", "None", "text", "a (1, 2) array"])
@pytest.mark.parametrize("query", ["free_many", "motion_free", "clearance_many", "min_clearance", "check_path"])
def test_many_pose_queries_name_the_poses(world, query, bad):
    _, w = world
    fp = default_robot("rwd_car").footprint
    value = BAD_POSES[bad]
    if bad in ("two numbers", "a car's full state", "NaN"):
        value = [[3.0, 2.0, 0.0], value]          # one bad row among good ones
    with pytest.raises(InputError, match="'poses' must be an \\(N, 3\\) array"):
        getattr(w, query)(value, fp)


def test_many_pose_queries_accept_one_pose_and_min_clearance_refuses_none(world):
    _, w = world
    fp = default_robot("unicycle").footprint
    assert w.free_many((3.0, 2.0, 0.0), fp).tolist() == [True]
    assert w.free_many(np.zeros((0, 3)), fp).shape == (0,)
    with pytest.raises(InputError, match="N >= 1"):
        w.min_clearance(np.zeros((0, 3)), fp)


def test_check_poses_names_the_pose(world):
    m, w = world
    fp = default_robot("unicycle").footprint
    with pytest.raises(InputError, match="'goal' must be a pose"):
        check_poses(m, fp, {"start": (3.0, 2.0, 0.0), "goal": (15.0, 2.0)}, world=w)
    assert set(check_poses(m, fp, {"start": (3.0, 2.0, 0.0), "goal": None}, world=w)) == {"start"}
