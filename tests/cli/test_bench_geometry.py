"""``nhstab bench geometry``: its structure, and the answers of each case's two ways agree."""

from __future__ import annotations

import json

import pytest
from nhstab.bench import BENCHMARKS
from nhstab.bench import geometry as bg


@pytest.fixture(scope="module")
def bench():
    return bg.bench_geometry(repeats=1)


def test_structure_and_rows(bench):
    assert "geometry" in BENCHMARKS
    json.dumps(bench)
    assert bench["benchmark"] == "geometry" and bench["baseline"] == bg.BASELINE
    cases = [r["case"] for r in bench["rows"]]
    assert len(cases) == len(set(cases)) == 10
    assert bench["replaced_by_shapely"] == [r["case"] for r in bench["rows"] if r["library"] == "shapely"]
    for r in bench["rows"]:
        assert r["library"] in ("shapely", "ours") and r["repeats"] == 1
        assert r["ours_us"] > 0 and r["shapely_us"] > 0
        assert r["ours_over_shapely"] == pytest.approx(r["ours_us"] / r["shapely_us"])
        assert (r["reason_kept"] == "") == (r["library"] == "shapely")
    lines = bg.summary_lines(bench)
    assert len(lines) == len(cases)
    assert all(ln.startswith("| geometry | ") and ln.endswith(" |") for ln in lines)


def test_the_two_ways_agree(bench):
    """Booleans and hulls exactly; distances and areas to 1e-12 m (1e-12 m^2); the kept batched distances
    differ from GEOS's by rounding only."""
    for r in bench["rows"]:
        assert r["max_abs_difference"] <= 1e-12, r
    assert bench["met"]["every replaced case agrees with its baseline (max_abs_difference <= 1e-12)"]
