"""Library functions the commands call (the CLI only parses and prints): the noise merge of
``nhstab run``, the plannable check of ``nhstab plan`` / ``run``, the benchmark selection and the
bench.json merge of ``nhstab bench --only``."""

from __future__ import annotations

import gzip
import json

import numpy as np
import pytest
from nhstab.bench import BENCHMARKS, previous_results, select_benchmarks
from nhstab.errors import InputError
from nhstab.execution.config import DEFAULT_NOISE, NoiseOptions
from nhstab.planning import PLANNABLE, check_plannable
from nhstab.records import write_json_gz
from nhstab.robot import default_robot


def test_noise_merge_keeps_the_given_levels_and_adds_the_flags():
    base = NoiseOptions(scale=2.0, sensor={"x": 0.5, "y": 0.4}, process={"theta": 0.3})
    out = base.merged({"initial": None, "sensor": {"y": 0.1, "theta": 0.2}, "process": {}}, None)
    assert out.sensor == {"x": 0.5, "y": 0.1, "theta": 0.2} and out.process == {"theta": 0.3}
    assert out.initial == {} and out.scale == 2.0 and base.sensor == {"x": 0.5, "y": 0.4}     # base unchanged
    assert base.merged(None, 0.0).scale == 0.0 and base.merged({}, None) == base
    names = ("x", "y", "theta", "phi")
    # the merged levels, else the default level, times the scale
    expected = 2.0 * np.array([0.5, 0.1, 0.2, DEFAULT_NOISE["sensor"]["phi"]])
    assert np.array_equal(out.vector("sensor", names), expected)


def test_check_plannable_names_the_key_the_robot_came_from():
    for name in PLANNABLE:
        check_plannable(default_robot(name), "--robot")
    with pytest.raises(InputError) as err:
        check_plannable(default_robot("heisenberg"), "robot.model (in yard.yaml)")
    assert err.value.argument == "robot.model (in yard.yaml)" and "the robots nhstab plans for" in str(err.value)
    assert "heisenberg" in str(err.value)


def test_benchmark_selection_and_the_merge_base(tmp_path):
    assert select_benchmarks(None) == list(BENCHMARKS)
    assert select_benchmarks(" gains, startup,gains ") == ["gains", "startup"]     # each once, in the given order
    for bad in ("gains,nope", " , "):
        with pytest.raises(InputError) as err:
            select_benchmarks(bad)
        assert err.value.argument == "--only"
    assert previous_results(tmp_path) == {}                                        # no bench.json yet
    (tmp_path / "bench.json").write_text(json.dumps({"gains": {"a": 1}, "gone": {"b": 2}}))
    assert previous_results(tmp_path) == {"gains": {"a": 1}}                       # benchmarks that still exist
    for text in ("{not json", "[1, 2]"):
        (tmp_path / "bench.json").write_text(text)
        with pytest.raises(InputError) as err:
            previous_results(tmp_path)
        assert err.value.argument == "--out-dir"
    # what nhstab bench writes now, bench.json.gz, comes before an uncompressed bench.json
    write_json_gz(tmp_path / "bench.json.gz", {"run": {"c": 3}, "gone": {}})
    assert previous_results(tmp_path) == {"run": {"c": 3}} and not (tmp_path / "bench.json").exists()
    for data in (b"not gzip", gzip.compress(b"[1, 2]"), gzip.compress(b'{"run": {}}')[:-6]):
        (tmp_path / "bench.json.gz").write_bytes(data)
        with pytest.raises(InputError) as err:
            previous_results(tmp_path)
        assert err.value.argument == "--out-dir" and "bench.json.gz" in str(err.value)
