"""Geometric planning with OMPL: lengths against the steering cross-check table, statuses, clearance."""

import csv
from pathlib import Path

import numpy as np
import pytest
from nhstab.collision import CollisionWorld
from nhstab.geometry import Footprint
from nhstab.maps.base import Map, box_polygon
from nhstab.planning.geometric import PathOptions, path_length, plan_path

DATA = Path(__file__).parents[1] / "data" / "steering-crosscheck-cases.csv"


def _cases():
    with DATA.open() as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    return rows


CASES = _cases()
EMPTY = Map("empty", (-30.0, -30.0, 30.0, 30.0))


def test_table_has_both_kinds():
    kinds = {r["kind"] for r in CASES}
    assert kinds == {"reeds_shepp", "dubins"} and len(CASES) == 240


@pytest.mark.parametrize("kind", ["reeds_shepp", "dubins"])
def test_planner_path_lengths_match_crosscheck_table(kind):
    """Our planner's path in an empty world is the direct local path: its length equals the shortest
    Reeds-Shepp / Dubins length on which three independent implementations agree (1e-9 m)."""
    world = CollisionWorld.from_map(EMPTY)
    dot = Footprint.disc(0.01)
    rows = [r for r in CASES if r["kind"] == kind]
    worst = 0.0
    for r in rows:
        a = (float(r["x0"]), float(r["y0"]), float(r["theta0"]))
        b = (float(r["x1"]), float(r["y1"]), float(r["theta1"]))
        opts = PathOptions(space=kind, turning_radius=float(r["turning_radius"]), margin=0.0, resolution=0.5)
        ref = float(r["length_ompl"])
        assert abs(path_length(opts, a, b) - ref) < 1e-9
        g = plan_path(world, dot, a, b, opts)
        assert g.status == "exact"
        worst = max(worst, abs(g.length - ref))
        # the dense samples follow the same path: exact arc length at the end, and the chords add up
        # to it within one sampling step per cusp (a chord cuts across each cusp)
        assert abs(g.sigma[-1] - ref) < 1e-9
        chords = np.hypot(*np.diff(g.samples[:, :2], axis=0).T).sum()
        assert ref - chords < (g.cusps + 1) * 0.005 + 1e-6 and chords <= ref + 1e-9
    assert worst < 1e-9


def test_quarter_arc_trap():
    """(0,0,0) -> (1,1,pi/2) with radius 1 is one quarter arc: pi/2, not pi/2 + 2 pi."""
    for space in ("reeds_shepp", "dubins"):
        assert path_length(PathOptions(space=space, turning_radius=1.0), (0, 0, 0), (1, 1, np.pi / 2)) == \
            pytest.approx(np.pi / 2, abs=1e-9)


@pytest.mark.parametrize("guide", [True, False])
def test_plan_around_a_wall_is_clear_by_the_margin_and_seeded(guide):
    m = Map("wall", (0, 0, 20, 12), obstacles=(box_polygon(10, 4, 1.0, 8.0),))
    world = CollisionWorld.from_map(m)
    fp = Footprint.rectangle(1.0, 0.6, rear_overhang=0.2)
    opts = PathOptions(turning_radius=1.0, time_limit_s=2.0, seed=11, margin=0.2, guide=guide)
    g1 = plan_path(world, fp, (2, 3, 0), (18, 3, 0), opts)
    other = plan_path(world, fp, (2, 3, 0), (18, 3, 0), PathOptions(**{**opts.__dict__, "seed": 12}))
    g2 = plan_path(world, fp, (2, 3, 0), (18, 3, 0), opts)
    assert g1.status == "exact" and g1.info["planner_used"] == ("guided" if guide else "rrtconnect")
    np.testing.assert_array_equal(g1.waypoints, g2.waypoints)          # same seed, same plan, whatever ran between
    assert other.status == "exact"
    check = world.check_path(g1.samples, fp, margin=0.2, resolution=0.02)
    assert check.clear and check.min_clearance > 0.2
    assert np.all(g1.samples[:, 1] > 8.0 - 1e-9) or g1.samples[:, 1].max() > 8.0   # it went around the wall


def test_no_path_is_failed_not_an_exception():
    m = Map("closed", (0, 0, 20, 10), obstacles=(box_polygon(10, 5, 1.0, 10.0),))
    g = plan_path(CollisionWorld.from_map(m), Footprint.disc(0.2), (2, 5, 0), (18, 5, 0),
                  PathOptions(turning_radius=1.0, time_limit_s=0.3, margin=0.1))
    assert g.status in ("failed", "approximate")
    assert g.status != "exact"


@pytest.mark.parametrize("kwargs,arg", [({"planner": "astar"}, "planner"), ({"time_limit_s": 0.0}, "time_limit_s"),
                                        ({"turning_radius": 0.0}, "turning_radius"), ({"space": "hyperbolic"}, "space"),
                                        ({"margin": -1.0}, "margin"), ({"seed": -3}, "seed")])
def test_bad_options(kwargs, arg):
    from nhstab.errors import InputError

    with pytest.raises(InputError) as exc:
        PathOptions(**{"turning_radius": 1.0, "margin": 0.1, **kwargs}).validated()
    assert exc.value.argument == arg
