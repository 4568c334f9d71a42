"""The gzip-compressed JSON records (nhstab.records.write_json_gz, read_json, record_file): the large
records the study, sweep, bench and paper commands write into results/."""

from __future__ import annotations

import gzip
import json
import math

import numpy as np
import pytest
from nhstab.limits import MAX_FILE_BYTES
from nhstab.records import read_json, record_file, write_json, write_json_gz


def test_a_gzip_record_holds_the_json_text_byte_for_byte_and_the_same_record_the_same_bytes(tmp_path):
    obj = {"a": [0.1, 1e-300, 2 / 3, np.float64(np.pi), np.int64(7), math.nan], "b": {"c": True, "d": None}}
    write_json_gz(tmp_path / "x.json.gz", obj)
    text = gzip.decompress((tmp_path / "x.json.gz").read_bytes()).decode()
    assert text == '{"a":[0.1,1e-300,0.6666666666666666,3.141592653589793,7,null],"b":{"c":true,"d":null}}\n'
    assert read_json(tmp_path / "x.json.gz") == json.loads(text)
    # indented as write_json writes it
    indented = write_json(tmp_path / "y.json", obj).read_bytes()
    write_json_gz(tmp_path / "y.json.gz", obj, indent=2)
    assert gzip.decompress((tmp_path / "y.json.gz").read_bytes()) == indented
    # no time stamp nor file name: the same record, the same bytes
    first = (tmp_path / "x.json.gz").read_bytes()
    write_json_gz(tmp_path / "sub" / "x.json.gz", obj)
    assert (tmp_path / "sub" / "x.json.gz").read_bytes() == first
    with pytest.raises(ValueError):
        write_json_gz(tmp_path / "x.json", obj)


def test_the_gzip_record_replaces_an_uncompressed_one_and_is_found_first(tmp_path):
    assert record_file(tmp_path, "study.json") == tmp_path / "study.json.gz"          # neither: where it goes
    (tmp_path / "study.json").write_text('{"old": 1}')
    assert record_file(tmp_path, "study.json") == tmp_path / "study.json"             # an earlier nhstab's
    assert read_json(record_file(tmp_path, "study.json")) == {"old": 1}
    write_json_gz(tmp_path / "study.json.gz", {"new": 2})
    assert not (tmp_path / "study.json").exists()                                    # one form of each record
    assert record_file(tmp_path, "study.json") == tmp_path / "study.json.gz"
    assert read_json(record_file(tmp_path, "study.json")) == {"new": 2}


def test_a_damaged_gzip_record_raises_oserror_or_valueerror(tmp_path):
    whole = gzip.compress(b'{"a": [1, 2, 3]}\n')
    for name, data in (("not_gzip", b"{}"), ("cut", whole[:-5]), ("damaged", whole[:12] + b"\xff" * 8 + whole[20:]),
                       ("not_json", gzip.compress(b"{nope")), ("not_utf8", gzip.compress(b'"\xff"'))):
        path = tmp_path / f"{name}.json.gz"
        path.write_bytes(data)
        with pytest.raises((OSError, ValueError)):
            read_json(path)


def test_a_gzip_record_may_not_expand_past_the_file_limit(tmp_path, monkeypatch):
    import nhstab.records as records

    monkeypatch.setattr(records, "MAX_FILE_BYTES", 1000)
    path = tmp_path / "big.json.gz"
    path.write_bytes(gzip.compress(b"[" + b"0," * 1000 + b"0]"))              # 2 KB from a few bytes
    with pytest.raises(ValueError, match="expands to more than 1000 bytes"):
        read_json(path)
    assert MAX_FILE_BYTES > 1000
