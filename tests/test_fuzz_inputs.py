"""Fuzzing every parser and config format: only PipelineErrors escape, and bombs are refused fast.

One hypothesis test per parser and per config format not already fuzzed beside its loader (the Moving
AI, ROS, nhstab-YAML map and SVG path-data fuzzers live in test_maps_grid.py and test_maps_vector.py),
and one per YAML consumer for size and nesting bombs: deep nesting (flow and block), alias bombs
("billion laughs"), recursive aliases, duplicate keys and documents beyond the size limit. The bombs
run under a hypothesis deadline: each must be refused within it (they take milliseconds; the
deadline is generous because the machine is shared), never hang, never exhaust memory.
"""

from __future__ import annotations

import io
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from nhstab.batch.config import load_batch_config
from nhstab.batch.report import write_report
from nhstab.errors import InputError, PipelineError
from nhstab.execution.config import load_run_config
from nhstab.limits import MAX_YAML_BYTES, MAX_YAML_DEPTH
from nhstab.maps import load_map
from nhstab.maps.ros import read_map_yaml
from nhstab.maps.svg import load_benchmr_scenarios, load_benchmr_svg
from nhstab.models import make_model
from nhstab.safe_io import load_yaml
from nhstab.trajectory_io import read_trajectory

ROOT = Path(__file__).resolve().parents[1]
ROOM = ROOT / "maps/ours/cluttered_room.yaml"
STORE = ROOT / "tests/data/store_schema1.sqlite"

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                      HealthCheck.function_scoped_fixture])
#: bombs must be refused within this (they take milliseconds)
BOMBS = settings(max_examples=25, deadline=timedelta(seconds=5),
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def only_pipeline_errors(call):
    try:
        return call()
    except PipelineError:
        return None


# ---- bombs ----------------------------------------------------------------------------------

def nesting_bomb(depth: int, style: str) -> str:
    if style == "flow-list":
        return "[" * depth + "]" * depth
    if style == "flow-map":
        return "{a: " * depth + "1" + "}" * depth
    return "\n" + "".join("  " * i + "- \n" for i in range(depth))       # block lists


def alias_bomb(levels: int, fanout: int) -> str:
    lines = ["  l0: &l0 [" + ", ".join(["lol"] * fanout) + "]"]
    for k in range(1, levels):
        lines.append(f"  l{k}: &l{k} [" + ", ".join([f"*l{k - 1}"] * fanout) + "]")
    return "\n" + "\n".join(lines) + "\n"


BOMB = st.one_of(
    st.builds(lambda d, s: ("nesting", nesting_bomb(d, s)), st.integers(MAX_YAML_DEPTH + 1, 4000),
              st.sampled_from(["flow-list", "flow-map", "block"])),
    st.builds(lambda lv, f: ("alias", alias_bomb(lv, f)), st.integers(8, 14), st.integers(7, 12)),
    st.just(("recursive", " &r [*r, 1]\n")),
)


def documents(bomb: str, kind: str) -> dict[str, str]:
    """The bomb placed where each YAML consumer will read it."""
    return {
        "yaml": f"x: {bomb}",
        "map": f"name: b\nbounds: [0, 0, 10, 10]\nrobot:\n  model: unicycle\n  extra: {bomb}",
        "ros": f"image: m.pgm\nresolution: 0.05\norigin: {bomb}",
        "run": f"seed: 1\nnoise: {bomb}",
        "batch": f"root_seed: 1\ntrials: 1\nmaps: [{{path: {ROOM}}}]\nrun: {bomb}",
    }


def _refused_by_every_consumer(tmp_path, text_by_consumer: dict, needle: str | None = None) -> None:
    for consumer, text in text_by_consumer.items():
        path = tmp_path / f"{consumer}.yaml"
        path.write_text(text)
        call = {"yaml": lambda: load_yaml(text, "doc.yaml"), "map": lambda: load_map(path),
                "ros": lambda: read_map_yaml(path), "run": lambda: load_run_config(path),
                "batch": lambda: load_batch_config(path)}[consumer]
        with pytest.raises(InputError) as err:
            call()
        message = str(err.value)
        assert "\n" not in message, (consumer, message)
        if needle:
            assert needle in message, (consumer, message)


@BOMBS
@given(bomb=BOMB)
def test_bombs_are_refused_fast_by_every_yaml_reader(tmp_path, bomb):
    kind, text = bomb
    needle = {"nesting": "nested", "alias": "aliases expanded", "recursive": "recursive"}[kind]
    if kind == "nesting":
        needle = None       # libyaml refuses very deep flow nesting itself ("maximum nesting depth")
    _refused_by_every_consumer(tmp_path, documents(text, kind), needle)


@BOMBS
@given(key=st.sampled_from(["a", "seed", "model", "x_1"]), depth=st.integers(0, 5))
def test_duplicate_keys_are_refused_naming_the_key(tmp_path, key, depth):
    inner = f"{key}: 1\n{key}: 2\n"
    text = inner
    for _ in range(depth):
        text = "n:\n" + "".join("  " + line + "\n" for line in text.splitlines())
    with pytest.raises(InputError, match=f"'doc.yaml: {'n.' * depth}{key}' must be a key given once"):
        load_yaml(text, "doc.yaml")


def test_documents_beyond_the_size_limit_are_refused_before_parsing(tmp_path):
    path = tmp_path / "big.yaml"
    with open(path, "wb") as fh:
        fh.write(b"a: [")
        fh.truncate(MAX_YAML_BYTES + 10)            # sparse: no time spent writing it
    for call in (lambda: load_map(path), lambda: load_run_config(path), lambda: load_batch_config(path),
                 lambda: read_map_yaml(path)):
        with pytest.raises(InputError, match="at most 1,048,576 bytes"):
            call()


# ---- config formats ----------------------------------------------------------------------------

SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-3, 10**6), st.integers(min_value=2**60),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                    st.sampled_from(["1e9", "gramian", "tvlqr", "future", "uniform", "x", "theta", "example:nowhere"]))
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                        st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                      max_leaves=8)
RUN_KEYS = st.sampled_from(["robot", "start", "goal", "seed", "rate_hz", "substeps", "saturate", "headroom",
                            "max_time_s", "controller", "noise", "sensor", "monitor", "planning", "replan",
                            "tolerance", "extra"])
SECTION = {"controller": ["kind", "window", "alpha", "delta", "gamma", "q", "r", "type"],
           "noise": ["scale", "initial", "sensor", "process", "impulses"],
           "sensor": ["range_m", "fov_deg", "rate_hz", "resolution_deg", "mount"],
           "monitor": ["rate_hz", "horizon_s"], "planning": ["planner", "time_limit_s", "margin", "space"],
           "replan": ["pause_s", "max_attempts", "max_replans"], "tolerance": ["position_m", "heading_rad"]}


@st.composite
def run_configs(draw) -> dict:
    doc = draw(st.dictionaries(RUN_KEYS, VALUES, max_size=5))
    for sec, keys in SECTION.items():
        if draw(st.booleans()) and draw(st.booleans()):
            doc[sec] = draw(st.dictionaries(st.sampled_from(keys), VALUES, max_size=3))
    return doc


@FUZZ
@given(doc=run_configs())
def test_fuzz_run_config(tmp_path, doc):
    from nhstab.execution import RunOptions  # noqa: F401 - the options a loaded config must validate to

    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(doc))
    loaded = only_pipeline_errors(lambda: load_run_config(path))
    if loaded is not None:
        _, opts = loaded
        model = make_model("unicycle")
        only_pipeline_errors(lambda: opts.validated(model.state_names, model.m))


BATCH_KEYS = st.sampled_from(["name", "root_seed", "trials", "robots", "controllers", "grid", "run", "extra"])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(doc=st.dictionaries(BATCH_KEYS, VALUES, max_size=4),
       seed=st.one_of(st.integers(0, 2**64), st.integers(min_value=2**200), st.text(max_size=4)),
       trials=st.one_of(st.integers(-2, 3), st.integers(min_value=10**6), st.sampled_from(["1e3", 1.5])),
       problems=st.one_of(st.just("map"), VALUES,
                          st.lists(st.fixed_dictionaries({"start": st.lists(st.floats(-5, 20), min_size=3, max_size=3),
                                                          "goal": st.lists(st.floats(-5, 20), min_size=3, max_size=3)}),
                                   min_size=1, max_size=2)))
def test_fuzz_batch_config(tmp_path, doc, seed, trials, problems):
    doc = {"root_seed": seed, "trials": trials, "maps": [{"path": str(ROOM), "problems": problems}], **doc}
    path = tmp_path / "batch.yaml"
    path.write_text(yaml.safe_dump(doc))
    config = only_pipeline_errors(lambda: load_batch_config(path))
    if config is not None:
        assert 1 <= config.n_trials() <= 10**6
        config.fingerprint()


# ---- other parsers -----------------------------------------------------------------------------

SVG_BITS = st.sampled_from(['<svg xmlns="http://www.w3.org/2000/svg">', "</svg>", '<path d="M 0 0 L 10 0 L 0 10 Z"/>',
                            '<path d="M 1e200 0 L 1 1 L 0 1 Z"/>', '<path d="M 0 0 l 1e308 0 l 0 1e308 z"/>',
                            "<g>", "</g>", "<!DOCTYPE x [<!ENTITY a 'aaaa'>]>", "&a;", "<rect/>", "<", ">", "\"",
                            '<path d="M 0 0 L 1 0 L 1 1 L 0 1 Z" id="p"/>', "<?xml version='1.0'?>"])


@FUZZ
@given(parts=st.lists(SVG_BITS, max_size=8), junk=st.text(max_size=20))
def test_fuzz_svg_files(tmp_path, parts, junk):
    path = tmp_path / "f.svg"
    path.write_text("".join(parts) + junk, encoding="utf-8", errors="surrogatepass")
    m = only_pipeline_errors(lambda: load_benchmr_svg(path))
    if m is not None:
        assert all(np.isfinite(p.vertices).all() for p in m.obstacles)


CSV_BITS = st.sampled_from(["environment,case,start_x,start_y,start_theta,goal_x,goal_y,goal_theta,robot_shape\n",
                            "parking1,0,1,2,0,3,4,0,car.svg\n", "x,1,nan,2,0,3,4,0,c\n", "# comment\n", ",,,\n",
                            "p,1,1e999,0,0,0,0,0,c\n", "p,2,1,2,3\n", "\n"])


@FUZZ
@given(parts=st.lists(CSV_BITS, max_size=6), junk=st.text(max_size=20))
def test_fuzz_benchmr_scenario_csv(tmp_path, parts, junk):
    path = tmp_path / "polygon_scenarios.csv"
    path.write_text("".join(parts) + junk, encoding="utf-8", errors="surrogatepass")
    only_pipeline_errors(lambda: load_benchmr_scenarios(path))


TRAJ_BITS = st.sampled_from(["t [s],x [m],y [m],theta [rad],v [m/s],omega [rad/s]\n", "0,0,0,0,1,0\n",
                             "1,1,0,0,1,0\n", "1,1,0,0,1,0\n", "0.5,0.5,0,0,1,0\n", "2,nan,0,0,1,0\n", "x,y\n",
                             "3,3,0,0,1,0,9\n", "1e400,0,0,0,1,0\n"])


@FUZZ
@given(parts=st.lists(TRAJ_BITS, max_size=6), npz=st.booleans(), junk=st.binary(max_size=30))
def test_fuzz_trajectory_files(tmp_path, parts, npz, junk):
    model = make_model("unicycle")
    if npz:
        path = tmp_path / "t.npz"
        buf = io.BytesIO()
        np.savez(buf, t=np.array([0.0, 1.0, 1.0]), x=np.zeros((3, 3)), u=np.ones((3, 2)))
        data = buf.getvalue()
        path.write_bytes(data[:len(data) * len(parts) // 6] + junk)
    else:
        path = tmp_path / "t.csv"
        path.write_text("".join(parts))
    only_pipeline_errors(lambda: read_trajectory(path, model))


@pytest.fixture(scope="module")
def store_bytes():
    return STORE.read_bytes()


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(cut=st.floats(0, 1), flips=st.lists(st.tuples(st.floats(0, 1), st.integers(1, 255)), max_size=4),
       wal_header=st.booleans())
def test_fuzz_batch_stores(tmp_path_factory, store_bytes, cut, flips, wal_header):
    """Truncated and corrupted copies of a real store: a report is written, or one InputError."""
    d = tmp_path_factory.mktemp("store")
    data = bytearray(store_bytes[:int(cut * len(store_bytes))])
    for where, delta in flips:
        if data:
            k = int(where * (len(data) - 1))
            data[k] = (data[k] + delta) % 256
    if not wal_header and len(data) > 20:
        data[18:20] = b"\x01\x01"
    path = d / "trials.sqlite"
    path.write_bytes(bytes(data))
    before = path.read_bytes()
    only_pipeline_errors(lambda: write_report(path, d / "report"))
    assert path.read_bytes() == before                   # a report never writes to the store
    assert sorted(p.name for p in d.iterdir()) in (["trials.sqlite"], ["report", "trials.sqlite"])
