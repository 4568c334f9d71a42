"""The command line: exit codes, one-line errors, the files commands write."""

import json

import numpy as np
import pytest
from click.testing import CliRunner
from nhstab.cli.main import cli
from nhstab.control import StabilizerOptions, compute_schedule
from nhstab.nominal import Nominal
from nhstab.records import read_json
from nhstab.trajectory_io import write_trajectory
from nominals import hilare_sinusoid


@pytest.fixture
def runner():
    return CliRunner()


def _one_line_error(result, *needles):
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.output
    for needle in needles:
        assert needle in lines[0], lines[0]


@pytest.mark.slow
def test_paper_single_case(runner, tmp_path):
    res = runner.invoke(cli, ["paper", "--case", "hilare-circle", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    summary = read_json(tmp_path / "summary.json.gz")
    (case,) = summary["cases"]
    assert case["case"] == "hilare-circle" and case["status"] == "converged"
    assert case["final_error_norm"] < 1e-3 * case["initial_error_norm"]
    for kind in ("errors", "inputs", "phase", "gramian"):
        assert (tmp_path / f"hilare-circle-{kind}.png").exists()


@pytest.mark.slow
def test_paper_override_is_recorded(runner, tmp_path):
    res = runner.invoke(cli, ["paper", "--case", "hilare-circle", "--alpha", "0.3", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert read_json(tmp_path / "summary.json.gz")["cases"][0]["alpha"] == 0.3


@pytest.mark.parametrize("args,needles", [
    (["--gamma", "0.4"], ["'--gamma'", "1/2", "0.4"]),
    (["--alpha", "0"], ["'--alpha'", "positive"]),
    (["--alpha", "-1"], ["'--alpha'"]),
    (["--delta", "0"], ["'--delta'", "positive"]),
    (["--delta", "-3"], ["'--delta'"]),
    (["--case", "moon-landing"], ["'--case'", "moon-landing"]),
    (["--window", "sideways"], ["--window", "sideways"]),
    (["--gamma", "lots"], ["--gamma", "lots"]),
])
def test_paper_bad_input(runner, tmp_path, args, needles):
    _one_line_error(runner.invoke(cli, ["paper", "--out", str(tmp_path), *args]), *needles)
    assert not (tmp_path / "summary.json.gz").exists()


@pytest.fixture
def traj(tmp_path):
    return write_trajectory(tmp_path / "hilare.csv", hilare_sinusoid(2 * np.pi, hz=100))


def test_gains_command(runner, tmp_path, traj):
    out = tmp_path / "g"
    res = runner.invoke(cli, ["gains", str(traj), "--model", "unicycle", "--alpha", "0.1", "--delta", "1",
                              "--out", str(out)])
    assert res.exit_code == 0, res.output
    diag = json.loads((out / "gains.json").read_text())
    data = np.load(out / "gains.npz")
    nom = hilare_sinusoid(2 * np.pi, hz=100)
    sampled = Nominal.from_samples(nom.model, nom.t, nom.x, nom.u)     # what the file holds
    ref = compute_schedule(sampled, StabilizerOptions(alpha=0.1, delta=1.0))
    np.testing.assert_allclose(data["K"], ref.K, rtol=1e-12, atol=1e-12)
    assert diag["rate_bound"] == pytest.approx(ref.diagnostics["rate_bound"], rel=1e-12)
    assert diag["weighting"] == "exp(6 alpha (t - tau))" and diag["model"] == "unicycle"


def test_gains_reports_the_3_alpha_bound_and_warns_once_for_the_past_window(runner, tmp_path, traj):
    out = tmp_path / "g"
    res = runner.invoke(cli, ["gains", str(traj), "--model", "unicycle", "--out", str(out)])
    assert res.exit_code == 0 and "guaranteed rate 3 alpha = 0.6 1/s" in res.stdout   # the unicycle's alpha 0.2
    diag = json.loads((out / "gains.json").read_text())
    assert diag["rate_bound"] == pytest.approx(0.6) and diag["rate_bound_printed"] < 0.6
    res = runner.invoke(cli, ["gains", str(traj), "--model", "unicycle", "--window", "past", "--out", str(out)])
    assert res.exit_code == 0, res.output
    warnings = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(warnings) == 1 and warnings[0].startswith("nhstab: warning: the past window (Remark 2) is not "
                                                         "stabilizing in general")
    assert json.loads((out / "gains.json").read_text())["rate_bound"] is None
    res = runner.invoke(cli, ["gains", str(traj), "--model", "unicycle", "--window", "frozen-time", "--out", str(out)])
    assert res.exit_code == 0 and not res.stderr.strip()
    assert json.loads((out / "gains.json").read_text())["frozen_time"]["max_gain"] == 50.0
    _one_line_error(runner.invoke(cli, ["gains", str(traj), "--model", "unicycle", "--end-strategy", "switch",
                                        "--out", str(out)]), "--end-strategy", "switch")


def test_gains_bad_inputs(runner, tmp_path, traj):
    base = ["gains", str(traj), "--out", str(tmp_path / "o")]
    _one_line_error(runner.invoke(cli, [*base, "--model", "hovercraft"]), "'--model'", "hovercraft")
    _one_line_error(runner.invoke(cli, [*base, "--model", "unicycle", "--gamma", "0.1"]), "'--gamma'")
    _one_line_error(runner.invoke(cli, [*base, "--model", "fwd_car"]), "header", "fwd_car")
    _one_line_error(runner.invoke(cli, [*base, "--model", "unicycle", "--delta", "50"]), "'--delta'", "duration")
    # a window far shorter than the time step (0.01 s here): 1e10 substeps per step were allocated (a
    # MemoryError traceback); the shortest is 0.01 / (1/16 x 1024) s
    _one_line_error(runner.invoke(cli, [*base, "--model", "unicycle", "--delta", "1e-12"]), "'--delta'",
                    "at least 0.000156 s")
    _one_line_error(runner.invoke(cli, [*base, "--model", "unicycle", "--param", "wheelbase=2"]), "'--param'", "wheelbase")
    lines = traj.read_text().splitlines()
    lines[5] = lines[5].replace(lines[5].split(",")[2], "nan", 1)
    bad = tmp_path / "nan.csv"
    bad.write_text("\n".join(lines) + "\n")
    _one_line_error(runner.invoke(cli, ["gains", str(bad), "--model", "unicycle", "--out", str(tmp_path / "o")]),
                    "must be finite")
    npz = tmp_path / "shape.npz"
    np.savez(npz, t=np.linspace(0, 5, 6), x=np.zeros((6, 3)), u=np.zeros((5, 2)))
    _one_line_error(runner.invoke(cli, ["gains", str(npz), "--model", "unicycle", "--out", str(tmp_path / "o")]),
                    "'u' must be shape (6, 2)")
    assert not (tmp_path / "o").exists()


def test_singular_trajectory_via_cli(runner, tmp_path):
    t = np.linspace(0, 5, 51)
    npz = tmp_path / "still.npz"
    np.savez(npz, t=t, x=np.zeros((51, 3)), u=np.zeros((51, 2)))
    res = runner.invoke(cli, ["gains", str(npz), "--model", "unicycle", "--out", str(tmp_path / "o")])
    _one_line_error(res, "singular at t = 0 s", "rank")


def test_version_and_help(runner):
    assert runner.invoke(cli, ["--version"]).exit_code == 0
    res = runner.invoke(cli, ["--help"])
    assert res.exit_code == 0 and "paper" in res.output and "gains" in res.output and "bench" in res.output


def test_every_benchmark_has_a_subcommand():
    from nhstab.bench import BENCHMARKS
    from nhstab.cli.bench import SUBCOMMANDS

    assert set(SUBCOMMANDS) == set(BENCHMARKS)


def test_bench_only_merges_into_the_existing_results(runner, tmp_path, monkeypatch):
    """`nhstab bench --only a,b` runs those benchmarks, keeps the others' stored results, and rewrites
    summary.md from the merged file; an unknown name is one line naming --only (exit code 2). The stored
    results of an earlier nhstab, an uncompressed bench.json, are merged into bench.json.gz, which
    replaces it."""
    import nhstab.bench as bench_pkg

    calls = []
    fake = {"gains": lambda: calls.append("gains") or {"new": 1}, "collision": lambda: calls.append("collision") or {}}
    monkeypatch.setattr(bench_pkg, "BENCHMARKS", fake)
    monkeypatch.setattr(bench_pkg, "summary_markdown", lambda results: "# merged\n" + json.dumps(results, sort_keys=True))
    (tmp_path / "bench.json").write_text(json.dumps({"gains": {"old": 1}, "collision": {"kept": True}}))
    res = runner.invoke(cli, ["bench", "--out-dir", str(tmp_path), "--only", "gains"])
    assert res.exit_code == 0, res.output
    assert calls == ["gains"]
    merged = read_json(tmp_path / "bench.json.gz")
    assert merged == {"gains": {"new": 1}, "collision": {"kept": True}} and not (tmp_path / "bench.json").exists()
    assert json.loads((tmp_path / "summary.md").read_text().split("\n", 1)[1]) == merged
    res = runner.invoke(cli, ["bench", "--out-dir", str(tmp_path), "--only", "gains,nope"])
    _one_line_error(res, "--only", "nope")
    assert read_json(tmp_path / "bench.json.gz") == merged
    calls.clear()
    assert runner.invoke(cli, ["bench", "--out-dir", str(tmp_path), "--only", "gains, gains,"]).exit_code == 0
    assert calls == ["gains"]                          # each benchmark once
    res = runner.invoke(cli, ["bench", "--only", "gains", "collision", "--out", str(tmp_path / "c.json")])
    _one_line_error(res, "--only", "collision")
    assert calls == ["gains"] and not (tmp_path / "c.json").exists()
