"""One loader for every YAML file nhstab reads: the same bad input gives the same style of error for a
map (nhstab's format and map_server metadata), a robot, a run config and a batch config: one line, an
InputError (a MapError for maps), naming the file and, where one applies, the key."""

from __future__ import annotations

import pytest
from nhstab.batch.config import load_batch_config
from nhstab.errors import InputError
from nhstab.execution.config import load_run_config
from nhstab.limits import MAX_YAML_BYTES
from nhstab.maps import load_map
from nhstab.robot import load_robot

GOOD = {
    "map": "name: m\nbounds: [0, 0, 10, 10]\nstart: [1, 1, 0]\ngoal: [9, 9, 0]\n",
    "ros": "image: x.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.25\n",
    "robot": "model: unicycle\n",
    "run": "map: m.yaml\n",
    "batch": "root_seed: 1\ntrials: 2\nmaps: [{path: m.yaml}]\n",
}
LOAD = {"map": load_map, "ros": load_map, "robot": load_robot, "run": load_run_config, "batch": load_batch_config}
#: a number written 1e1, which YAML 1.1 reads as text, at a key each file kind checks as a number
ONE_E1 = {"map": ("name: m\nbounds: [0, 0, 1e1, 10]\n", "bounds[2]"),
          "robot": ("model: unicycle\nmax_speed: 1e0\n", "max_speed"),
          "run": ("map: m.yaml\nnoise: {scale: 1e-1}\n", "noise.scale"),
          "batch": ("root_seed: 1\ntrials: 1e1\nmaps: [{path: m.yaml}]\n", "trials")}


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "m.yaml").write_text(GOOD["map"])
    (tmp_path / "x.pgm").write_bytes(b"P5\n2 2\n255\n" + bytes([0, 254, 254, 254]))
    return tmp_path


def error_of(folder, kind: str, text: str) -> tuple[InputError, str]:
    path = folder / f"{kind}_bad.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        LOAD[kind](path)
    message = str(err.value)
    assert "\n" not in message and "Traceback" not in message
    return err.value, message


def test_the_good_files_load(folder):
    for kind, text in GOOD.items():
        (folder / f"{kind}.yaml").write_text(text)
        LOAD[kind](folder / f"{kind}.yaml")


@pytest.mark.parametrize("kind", sorted(GOOD))
def test_a_duplicate_key(folder, kind):
    first = GOOD[kind].splitlines()[0]
    err, message = error_of(folder, kind, GOOD[kind] + first + "\n")
    key = first.split(":")[0]
    assert err.argument.endswith(f"{kind}_bad.yaml: {key}")
    assert "must be a key given once in its mapping" in message and f"a second '{key}'" in message


@pytest.mark.parametrize("kind", sorted(GOOD))
def test_an_unknown_top_level_key(folder, kind):
    err, message = error_of(folder, kind, GOOD[kind] + "bogus_key: 1\n")
    assert f"{kind}_bad.yaml: " in err.argument and err.argument.endswith("bogus_key")
    if kind == "robot":        # a robot's keys depend on its model: its reader checks them, naming the model
        assert "one of model, " in message and "'bogus_key'" in message
    else:
        assert "must be one of the keys " in message and "got \"unknown key 'bogus_key'\"" in message


@pytest.mark.parametrize("kind", sorted(GOOD))
@pytest.mark.parametrize("text,got", [("- 1\n- 2\n", "'a list'"), ("42\n", "'an integer'"),
                                      ("just text\n", "'a string'")])
def test_a_top_level_that_is_not_a_mapping(folder, kind, text, got):
    err, message = error_of(folder, kind, text)
    assert err.argument.endswith(f"{kind}_bad.yaml")
    assert "mapping" in message and f"got {got} (at top level)" in message


@pytest.mark.parametrize("kind", sorted(GOOD))
def test_an_empty_file(folder, kind):
    err, message = error_of(folder, kind, "")
    assert err.argument.endswith(f"{kind}_bad.yaml") and "mapping" in message
    assert "got 'an empty document'" in message


@pytest.mark.parametrize("kind", sorted(GOOD))
def test_a_key_that_is_not_text(folder, kind):
    err, message = error_of(folder, kind, GOOD[kind] + "1: 2\n")
    assert err.argument.endswith(f"{kind}_bad.yaml: 1")


@pytest.mark.parametrize("kind", sorted(GOOD))
def test_a_huge_file(folder, kind):
    _, message = error_of(folder, kind, GOOD[kind] + "#" * (MAX_YAML_BYTES + 10) + "\n")
    assert f"{kind}_bad.yaml" in message and f"at most {MAX_YAML_BYTES:,} bytes" in message


@pytest.mark.parametrize("kind", sorted(ONE_E1))
def test_a_number_yaml_reads_as_text(folder, kind):
    text, key = ONE_E1[kind]
    err, message = error_of(folder, kind, text)
    assert err.argument.endswith(key) and "YAML 1.1 reads 1e" in message and "as text: write 1.0e" in message


def test_map_server_metadata_reads_numbers_as_yaml_cpp_does(folder):
    """map_server's files are read as its yaml-cpp reads them: 5e-2 is a number there."""
    (folder / "ros.yaml").write_text(GOOD["ros"].replace("0.05", "5e-2"))
    assert load_map(folder / "ros.yaml").meta["resolution"] == 0.05
