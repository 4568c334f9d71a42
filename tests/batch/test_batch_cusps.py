"""A batch on a car maneuver with cusps: the gain schedule is split at the cusps, and the guaranteed
bound a trial records ends at the first one (the guarantee does not cross a cusp)."""
import pytest
from clitools import invoke
from nhstab.batch.store import Store


@pytest.mark.slow
def test_a_trial_on_a_maneuver_with_cusps_records_the_bound_up_to_the_first_cusp(tmp_path):
    cfg = tmp_path / "batch.yaml"
    cfg.write_text("name: cusps\nroot_seed: 3\ntrials: 1\nmaps:\n  - path: example:parallel_rwd_car_120\n"
                   "controllers: [gramian]\n")
    res = invoke("batch", cfg, "--out", tmp_path / "b", "--workers", "1", "--no-progress")
    assert res.exit_code in (0, 1), res.output
    with Store(tmp_path / "b" / "trials.sqlite") as store:
        (trial,) = store.trials()
    assert trial["status"] != "error", trial.get("error")
    until = trial["metrics"]["guarantee_until_s"]           # the split schedule's first cusp
    series = trial["series"]
    dt = series["dt_s"]
    assert 0.0 < until < trial["metrics"]["first_plan_duration_s"]
    # the bound stops at the last series sample at or before the first cusp; the errors go on
    n = len(series["bound"])
    assert n >= 1 and len(series["error_norm"]) > n
    assert (n - 1) * dt <= until + 1e-6 < n * dt + 1e-6
