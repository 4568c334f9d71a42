"""``nhstab bench polygons`` at tiny sizes: its structure, and the answers of what it times (the
baseline and GEOS agree on every polygon and its non-simple twin; the footprint and the map keep every
vertex). No timing is asserted (the machine is shared)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from nhstab.bench import BENCHMARKS
from nhstab.bench import polygons as bp
from nhstab.geometry import is_simple_polygon, polygon_area

SIZES = (50, 100)


@pytest.fixture(scope="module")
def bench():
    return bp.bench_polygons(sizes=SIZES, repeats=1, baseline_repeats=1)


def test_structure_rows_and_targets(bench):
    assert "polygons" in BENCHMARKS
    json.dumps(bench)                                          # JSON-ready as it is
    assert bench["benchmark"] == "polygons" and bench["sizes"] == list(SIZES)
    assert bench["max_polygon_vertices"] == 10_000 and bench["at_max_size"] is False
    assert [(r["shape"], r["k"]) for r in bench["rows"]] == [(s, k) for s in bp.SHAPES for k in SIZES]
    for r in bench["rows"]:
        assert set(r["times"]) == set(bp.METHODS) == set(bench["methods"])
        for t in r["times"].values():
            assert t["repeats"] == 1 and 0 < t["best_s"] <= t["median_s"]
        assert r["times"]["map"]["median_s"] == pytest.approx(
            r["times"]["map_load"]["median_s"] + r["times"]["map_world"]["median_s"])
    for shape in bp.SHAPES:
        assert set(bench["exponents"][shape]) == set(bp.METHODS)
        assert all(isinstance(e, float) for e in bench["exponents"][shape].values())
        assert bench["speedup_over_baseline_at_max"][shape] > 0
    assert bench["targets"] == {"check_s_max": 1.0, "at_k": 100, "checks": list(bp.CHECKS), "star_exponent_max": 1.5}
    assert len(bench["met"]) == len(bp.SHAPES) * len(bp.CHECKS) + len(bp.CHECKS) + 1
    lines = bp.summary_lines(bench)
    assert all(ln.startswith("| polygons | ") and ln.count(" | ") == 4 and ln.endswith(" |") for ln in lines)
    assert any("below the maximum 10,000" in ln for ln in lines)


def test_every_polygon_measured_is_answered_alike_by_the_baseline_and_geos(bench):
    for r in bench["rows"]:
        assert r["geos_simple"] is r["baseline_simple"] is True, r
        assert r["twin_geos_simple"] is r["twin_baseline_simple"] is False, r
        assert r["agree"] and r["vertices"] == r["k"] == r["footprint_vertices"]
        assert r["map_obstacles"] == 1 and r["world_objects"] >= 1 and 0 < r["free_fraction"] < 1
    assert bench["met"]["baseline and GEOS agree on every polygon"]


@pytest.mark.parametrize("k", [6, 7, 8, 9, 37, 1_250])
def test_the_polygons_are_simple_with_exactly_k_vertices_and_their_twins_are_not(k):
    for shape in bp.SHAPES:
        ring = bp.polygon(shape, k, seed=3)
        assert ring.shape == (k, 2) and polygon_area(ring) != 0
        assert is_simple_polygon(ring) and bp.pairwise_is_simple(ring)
        twin = bp.non_simple_twin(ring, seed=3)
        assert not is_simple_polygon(twin) and not bp.pairwise_is_simple(twin)


@pytest.mark.parametrize("ring,simple", [
    ([[0, 0], [1, 0], [0, 1]], True),
    ([[0, 0], [1, 1], [1, 0], [0, 1]], False),                          # a bowtie: a proper crossing
    ([[0, 0], [2, 0], [2, 2], [1, 0], [0, 2]], False),                  # a vertex on another edge
    ([[0, 0], [2, 0], [1, 0], [1, 1]], False),                          # folded back onto the previous edge
    ([[0, 0], [1, 0], [2, 0], [2, 1], [0, 1]], True),                   # collinear neighbours, straight on
    ([[0, 0], [1, 0], [1, 0], [0, 1]], False),                          # an edge of zero length
    ([[0, 0], [4, 0], [4, 4], [2, 0.0], [0, 4]], False),                # touching at a point of an edge
    ([[0, 0], [4, 0], [4, 4], [0, 4], [2, 4]], False),                  # the closing edge folds back
])
def test_the_baseline_answers_like_geos_on_degenerate_rings(ring, simple):
    ring = np.array(ring, dtype=float)
    assert bp.pairwise_is_simple(ring) is simple
    assert is_simple_polygon(ring) is simple
    assert bp.pairwise_is_simple(ring, block_pairs=1) is simple       # one row of pairs per block


def test_the_command_writes_json(tmp_path):
    from nhstab.cli.main import cli

    out = tmp_path / "p.json"
    res = CliRunner().invoke(cli, ["bench", "polygons", "--size", "30", "--size", "60", "--out", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    assert data["benchmark"] == "polygons" and data["sizes"] == [30, 60]
    assert all(r["agree"] for r in data["rows"])
