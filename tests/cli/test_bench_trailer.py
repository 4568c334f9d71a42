"""``nhstab bench trailer``: the cases its targets cover, one real row, the totals and the summary."""

from __future__ import annotations

import csv
import json

from click.testing import CliRunner
from nhstab.batch.trailer_study import data_root
from nhstab.bench import BENCHMARKS
from nhstab.bench import trailer as bt
from nhstab.cli.main import cli


def test_the_targets_cover_the_suite_cases_at_1_2x_widths_and_above():
    with open(data_root() / "trailer" / "suite" / "suite.csv", encoding="utf-8", newline="") as fh:
        rows = list(csv.DictReader(fh))
    want = [r["name"] for r in rows if float(r["aisle_factor"]) >= 1.2
            and (r["kind"] == "turn" or float(r["bay_factor"]) >= 1.2)]
    assert [r["name"] for r in bt.target_cases()] == want and len(want) == 12
    assert "trailer" in BENCHMARKS


def test_one_case_planned_both_ways_and_summarised(monkeypatch):
    """A real row (the 1.5 S turn, one seed, 10 s): nhstab's plan and the baseline's timed alike; the totals
    are the rows' counts, and the summary's lines say them."""
    monkeypatch.setattr(bt, "target_cases", lambda: [r for r in bt.suite_rows() if r["name"] == "trailer_turn_150"])
    b = bt.bench_trailer(seeds=1, budget_s=10.0)
    json.dumps(b)
    (row,) = b["rows"]
    for key in ("nhstab", "baseline"):
        (t,) = row[key]
        assert t["ok"] == (t["status"] == "ok" and t["time_s"] <= 10.0) and t["time_s"] > 0
        tot = b[key]
        assert tot["tries"] == 1 and tot["plans"] == int(t["ok"]) and tot["rate"] == float(t["ok"])
    assert row["nhstab"][0]["ok"]                       # the 1.5 S turn plans (results/trailer/suite/table.md)
    assert b["met"]["rate"] and b["met"]["median"] == (b["nhstab"]["median_s"] < 2.0)
    lines = bt.summary_lines(b)
    assert len(lines) == 3 and all(ln.startswith("| trailer | ") for ln in lines)
    assert "1/1" in lines[0] and "100 %" in lines[1]


def test_bad_options_are_refused_naming_them(tmp_path):
    for args, key in ((["--seeds", "0"], "--seeds"), (["--budget", "-1"], "--budget")):
        res = CliRunner().invoke(cli, ["bench", "trailer", *args, "--out", str(tmp_path / "t.json")])
        assert res.exit_code == 2 and key in res.output, res.output
