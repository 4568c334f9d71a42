"""``nhstab bench tube``'s auto-tube rows (the tube nhstab run and nhstab plan compute by default) are
consistent: a sampled row's certified clearance is an independent predict_tube's on the same plan, its N
is the scenario bound's, its ratio and medians come from the times it keeps, its parts add up to its
calls, and its baseline agrees with it. No timing is asserted (the machine is shared)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from nhstab.tubes.base import DEFAULT_DISCARDS, rollouts_needed

#: every test reads the benchmark that the module fixture runs once
pytestmark = pytest.mark.slow

SCENARIO, CASE = "parking_lot", "parallel_rwd_car_110"


@pytest.fixture(scope="module")
def bench():
    """The benchmark on one bundled scenario and one parking case, with the plans its tubes were computed
    for (a plan made again may differ: the planner's result depends on its time budget and the load)."""
    from nhstab.bench.tube import bench_tube

    plans = {}
    b = bench_tube(scenarios=(SCENARIO,), repeats=1, cases=[CASE], auto_repeats=2, baseline_plans=2,
                   baseline_rollouts=3, observe=lambda row, run, law, world: plans.update({row["name"]: (run, law)}))
    return b, plans


def test_sampled_rows_are_independent_predict_tubes_with_the_scenario_count(bench):
    """The row's tube is what nhstab run computes for that plan: predict_tube with the run's options,
    written out here (not the benchmark's helper), certified against the obstacles the run knows."""
    from nhstab.tubes.predict import predict_tube

    b, plans = bench
    rows = {r["name"]: r for r in b["auto_rows"]}
    assert set(rows) == set(plans) == {SCENARIO, CASE}
    assert rows[SCENARIO]["source"] == "bundled" and rows[CASE]["source"] == "parking"
    for name, row in rows.items():
        run, law = plans[name]
        tube = predict_tube(law, run.opts.noise, run.fp, run.robot_world, rate_hz=run.opts.rate_hz,
                            substeps=run.opts.substeps, model=run.model)
        assert row["kind"] == tube.kind == "sampled"
        N = rollouts_needed(0.997, 0.95, DEFAULT_DISCARDS)
        assert row["N"] == tube.certificate["rollouts"] == N == 2097 and tube.certificate["discards"] == 2
        assert row["samples"] == len(tube.t) and row["rollout_poses"] == N * len(tube.t)
        assert row["certified_clearance_m"] == tube.certified_clearance
        assert row["clearance_evaluations"] == tube.clearance_evaluations


def test_auto_rows_ratio_and_medians_come_from_the_kept_times(bench):
    bench = bench[0]
    for row in bench["auto_rows"]:
        plan, tube = np.array(row["plan_times_s"]), np.array(row["tube_times_s"])
        assert len(plan) == len(tube) == row["repeats"] == 2
        assert row["ratio"] == pytest.approx(float(np.median(tube / plan)), rel=1e-12)
        assert row["tube_s"] == pytest.approx(float(np.median(tube)), rel=1e-12)
        assert row["plan_s"] == pytest.approx(float(np.median(plan)), rel=1e-12)
        # the parts of each call add up to it (the rest is "other"), none negative; a sampled tube spends
        # time in every part of its own
        parts = row["parts_s"]
        total = np.sum([parts[k] for k in parts], axis=0)
        assert np.allclose(total, tube, rtol=1e-9) and all(min(v) >= 0.0 for v in parts.values())
        for k in ("rollouts_engine", "reduction", "certificate_queries", "certificate_bound_sort", "linear_attempt"):
            assert min(parts[k]) > 0.0, k
    sm = bench["sampled_summary"]
    ratios = [r["ratio"] for r in bench["auto_rows"]]
    assert sm["plans"] == 2 and sm["ratio_max"] == max(ratios) and sm["ratio_median"] == pytest.approx(np.median(ratios))
    assert sum(sm["parts_share"].values()) == pytest.approx(1.0, rel=1e-9)


def test_the_sampled_baseline_agrees_and_its_extrapolation_is_the_kept_times(bench):
    """One baseline per source (the first sampled plan of the bundled scenarios, of the parking cases): the
    same 3 rollouts one at a time and FCL at every pose give the sampled tube's reach and clearance."""
    bench = bench[0]
    assert [b["name"] for b in bench["sampled_baseline"]] == [SCENARIO, CASE]
    assert bench["met"]["sampled_baseline_agrees"]
    for b in bench["sampled_baseline"]:
        assert b["agrees"] and b["clearance_many_agrees"] and b["reach_max_diff_m"] <= 1e-9
        assert b["certified_clearance_m"] == pytest.approx(b["sampled_certified_clearance_m"], abs=1e-9)
        assert b["rollouts_run"] == 3 and b["N"] == 2097 and b["extrapolated"]
        assert b["baseline_s"] == pytest.approx((b["loop_s"] + b["clearance_s"]) * 2097 / 3, rel=1e-12)
        assert b["speedup_vs_baseline"] == pytest.approx(b["baseline_s"] / b["sampled_tube_s"], rel=1e-12)
        assert b["sampled_tube_s"] == next(r["tube_s"] for r in bench["auto_rows"] if r["name"] == b["name"])


def test_the_linear_rows_keep_their_target_and_the_result_is_json(bench):
    from nhstab.bench.tube import summary_lines
    from nhstab.records import to_jsonable

    bench = bench[0]
    assert bench["targets"] == {"tube_over_plan_max": 0.10} and len(bench["rows"]) == 1
    json.dumps(to_jsonable(bench))
    lines = summary_lines(bench)
    assert sum("tube auto" in line for line in lines) == 2 + 1 + 2      # two rows, the summary, two baselines
