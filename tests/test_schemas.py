"""The JSON Schemas of the YAML formats: shipped as generated, valid, satisfied by every bundled file,
one source of the loaders' keys, and listed key by key (with defaults) in the reference pages.

Checked with the ``jsonschema`` package (the test extra), which nhstab itself does not use."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner
from nhstab.batch.config import load_batch_config
from nhstab.cli.main import cli
from nhstab.errors import InputError
from nhstab.execution.config import RunOptions, load_run_config
from nhstab.maps.base import MapError
from nhstab.maps.yaml_format import parse_yaml_map
from nhstab.models import MODELS
from nhstab.robot import ROBOT_KEYS, STABILIZER_KEYS, load_robot
from nhstab.schema import build_schemas, schema_text, stale_schemas
from nhstab.yaml_keys import FORMATS, SCHEMA_DIR, schema

jsonschema = pytest.importorskip("jsonschema")

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "docs" / "reference"


def _validator(name: str):
    return jsonschema.Draft202012Validator(schema(name))


def _errors(name: str, data) -> list[str]:
    return [f"{list(e.absolute_path)}: {e.message[:160]}" for e in _validator(name).iter_errors(data)]


# ---- shipped as generated ------------------------------------------------------------------------

def test_shipped_schemas_are_what_the_generator_writes(tmp_path):
    assert sorted(p.name for p in SCHEMA_DIR.glob("*.schema.json")) == sorted(f"{n}.schema.json" for n in FORMATS)
    assert stale_schemas(SCHEMA_DIR) == [], "run `nhstab schema --out pipeline/schemas`"
    runner = CliRunner()
    assert runner.invoke(cli, ["schema", "--check", str(SCHEMA_DIR)]).exit_code == 0
    res = runner.invoke(cli, ["schema", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    for name in FORMATS:
        assert (tmp_path / f"{name}.schema.json").read_text() == (SCHEMA_DIR / f"{name}.schema.json").read_text()
    res = runner.invoke(cli, ["schema", "run-config"])
    assert res.exit_code == 0 and res.output == schema_text(build_schemas()["run-config"])
    (tmp_path / "robot.schema.json").write_text("{}\n")
    res = runner.invoke(cli, ["schema", "--check", str(tmp_path)])
    assert res.exit_code == 1 and "robot.schema.json" in res.output


@pytest.mark.parametrize("name", FORMATS)
def test_each_schema_is_a_valid_draft_2020_12_schema_with_descriptions(name):
    s = schema(name)
    assert s["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    jsonschema.Draft202012Validator.check_schema(s)

    def walk(node, path):                     # every property described
        if isinstance(node, dict):
            for key, sub in (node.get("properties") or {}).items():
                assert isinstance(sub, dict) and sub.get("description"), f"{name}: {path}.{key}"
            for key, sub in node.items():
                if key != "if":                   # a condition, not a property
                    walk(sub, f"{path}.{key}")
        elif isinstance(node, list):
            for i, sub in enumerate(node):
                walk(sub, f"{path}[{i}]")

    walk(s, "")


# ---- one source of the keys ------------------------------------------------------------------------

def test_run_config_sections_are_the_dataclasses_and_their_defaults():
    props = schema("run-config")["properties"]
    assert set(props) == {f.name for f in dataclasses.fields(RunOptions)} | {"map"}
    defaults = RunOptions()
    aliases = {"controller": {"type"}, "sensor": {"fov_deg", "resolution_deg"}}
    for section in ("controller", "sensor", "monitor", "planning", "replan", "tolerance", "tube"):
        value = getattr(defaults, section)
        keys = set(props[section]["properties"]) - aliases.get(section, set())
        assert keys == {f.name for f in dataclasses.fields(value)}, section
        for key, sub in props[section]["properties"].items():
            if "default" in sub and key in keys:
                d = getattr(value, key)
                assert sub["default"] == (list(d) if isinstance(d, tuple) else d), f"{section}.{key}"
    assert props["sensor"]["properties"]["fov_deg"]["default"] == pytest.approx(math.degrees(defaults.sensor.fov_rad))
    assert props["headroom"]["default"] == defaults.headroom and props["rate_hz"]["default"] == defaults.rate_hz
    assert set(props["tube"]["properties"]["kind"]["enum"]) >= {"auto", "linear", "sampled"}


def test_robot_keys_and_model_parameters_come_from_the_schema():
    robot = schema("robot")["$defs"]["robot"]
    assert ROBOT_KEYS == tuple(robot["properties"]) and STABILIZER_KEYS == tuple(schema("robot")["$defs"]
                                                                                   ["stabilizer"]["properties"])
    by_model = {c["if"]["properties"]["model"]["const"]: c["then"]["properties"] for c in robot["allOf"]}
    assert set(by_model) == set(MODELS) == set(robot["properties"]["model"]["enum"])
    for name, cls in MODELS.items():
        params = {f.name: f.default for f in dataclasses.fields(cls) if f.init}
        assert {k: v["default"] for k, v in by_model[name].items() if k not in ROBOT_KEYS} == \
            {k: list(v) if isinstance(v, tuple) else v for k, v in params.items()}, name
        built_in = cls.robot_defaults
        assert by_model[name]["margin"]["default"] == built_in["margin"]
        assert by_model[name]["footprint"]["default"] == built_in["footprint"]
        assert by_model[name]["stabilizer"]["default"] == built_in["stabilizer"]
        # a model without trailers takes no trailer_footprint (the loader refuses it too)
        trailer = {"model": name, "trailer_footprint": {"radius": 1.0}}
        assert bool(_errors("robot", trailer)) == ("trailer_footprint" not in built_in), name


# ---- every bundled file satisfies its schema -------------------------------------------------------

def _bundled() -> list[tuple[str, Path]]:
    out = []
    for path in sorted((ROOT / "maps").rglob("*.yaml")):
        data = yaml.safe_load(path.read_text())
        if "image" in data:                     # a ROS map_server file: not an nhstab format
            continue
        kind = "batch-config" if "trials" in data else "run-config" if path.parent.name == "configs" else "map"
        out.append((kind, path))
    out += [("batch-config", p) for p in sorted((ROOT / "results").glob("*/batch.yaml"))]
    return out


BUNDLED = _bundled()


def test_the_bundled_files_cover_every_format():
    kinds = {k for k, _ in BUNDLED}
    assert kinds == {"map", "run-config", "batch-config"} and len(BUNDLED) >= 50


@pytest.mark.parametrize("kind,path", BUNDLED, ids=[str(p.relative_to(ROOT)) for _, p in BUNDLED])
def test_bundled_file_satisfies_its_schema(kind, path):
    assert _errors(kind, yaml.safe_load(path.read_text())) == []


def test_built_in_robots_and_presets_satisfy_the_robot_schema():
    n = 0
    for name, cls in MODELS.items():
        specs = [{"model": name}, {"robot": {"model": name, "footprint": cls.robot_defaults["footprint"],
                                             "margin": cls.robot_defaults["margin"],
                                             "stabilizer": cls.robot_defaults["stabilizer"]}}]
        specs += [{"model": name, "name": preset, **spec} for preset, spec in cls.robot_presets.items()]
        for spec in specs:
            assert _errors("robot", spec) == [], (name, spec)
            n += 1
    assert n >= 2 * len(MODELS)


_PAGES = {"map-yaml": "map", "robot-yaml": "robot", "run-config": "run-config", "batch-config": "batch-config"}


def test_reference_page_examples_satisfy_their_schemas():
    n = 0
    for page, kind in _PAGES.items():
        for block in re.findall(r"```yaml\n(.*?)```", (REFERENCE / f"{page}.md").read_text(), re.S):
            data = yaml.safe_load(block)
            if isinstance(data, dict) and "image" not in data:
                assert _errors(kind, data) == [], (page, block[:80])
                n += 1
    assert n >= 4


# ---- invalid inputs: refused by the schema and by the loader, naming the key ------------------------

_MAP = "bounds: [0, 0, 10, 10]\n"
_BATCH = "root_seed: 0\ntrials: 1\nmaps: [{path: 'example:cluttered_room'}]\n"
INVALID = [
    # (format, YAML text, the key path the loader's error names)
    ("map", _MAP + "bogus: 1\n", "bogus"),
    ("map", _MAP + "obstacles: [{circle: {center: [1, 1], radius: -1}}]\n", "obstacles[0].circle.radius"),
    ("map", _MAP + "base: {format: ros, path: x.yaml, cell_size: 1}\n", "base.cell_size"),
    ("map", _MAP + "start: [1, 1, 'a']\n", "start"),
    ("robot", "model: unicycle\nwheelbase: 2.0\n", "wheelbase"),
    ("robot", "model: rwd_car\nmax_speed: -1\n", "max_speed"),
    ("robot", "robot: {model: rwd_car, stabilizer: {gamma: 0.1}}\n", "stabilizer.gamma"),
    ("robot", "model: rwd_car\nmargin: 'a'\n", "margin"),
    ("robot", "model: fwd_car\nmax_steer: 2.0\n", "max_steer"),
    ("robot", "model: rwd_car\ntrailer_footprint: {radius: 1.0}\n", "trailer_footprint"),
    ("run-config", "bogus: 1\n", "bogus"),
    ("run-config", "planning: {planner: nope}\n", "planning.planner"),
    ("run-config", "rate_hz: 0\n", "rate_hz"),
    ("run-config", "tube: {confidence: 1.5}\n", "tube.confidence"),
    ("run-config", "sensor: {fov_deg: 400}\n", "sensor.fov_deg"),
    ("run-config", "replan: {max_attempts: 0}\n", "replan.max_attempts"),
    ("run-config", "saturate: 'yes'\n", "saturate"),
    ("batch-config", _BATCH + "bogus: 1\n", "bogus"),
    ("batch-config", _BATCH + "run: {seed: 3}\n", "run.seed"),
    ("batch-config", "root_seed: 0\ntrials: 'a'\nmaps: [{path: 'example:cluttered_room'}]\n", "trials"),
    ("batch-config", _BATCH + "grid: {gamma: [0.1]}\n", "grid.gamma[0]"),
    ("batch-config", _BATCH + "controllers: [pid]\n", "controllers[0]"),
]


@pytest.mark.parametrize("kind,text,key", INVALID, ids=[f"{k}:{key}" for k, _, key in INVALID])
def test_invalid_input_is_refused_by_schema_and_loader(tmp_path, kind, text, key):
    assert _errors(kind, yaml.safe_load(text)), "the schema accepts it"
    path = tmp_path / "input.yaml"
    path.write_text(text)
    load = {"map": lambda p: parse_yaml_map(p.read_text(), p), "robot": load_robot,
            "run-config": lambda p: load_run_config(p)[1].validated(("x", "y", "theta"), 2),   # a unicycle's
            "batch-config": load_batch_config}[kind]
    with pytest.raises((InputError, MapError)) as exc:
        load(path)
    assert key in str(exc.value), str(exc.value)


# ---- the reference pages list every key, with its default -------------------------------------------

def _sections(page: str) -> dict[str, str]:
    """A reference page's text by ``##`` heading (the text before the first: ``""``)."""
    out, head = {"": []}, ""
    for line in (REFERENCE / f"{page}.md").read_text().splitlines():
        if line.startswith("## "):
            head = line[3:].strip()
            out[head] = []
        else:
            out[head].append(line)
    return {k: "\n".join(v) for k, v in out.items()}


def _rows(text: str) -> list[dict]:
    """The rows of every table of ``text``: {column header: cell}."""
    rows, header = [], None
    for line in text.splitlines():
        if not line.startswith("|"):
            header = None
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if header is None:
            header = cells
        elif not set(line) <= set("|-: "):
            rows.append(dict(zip(header, cells)))
    return rows


def _row(rows: list[dict], key: str, column: str | None = None) -> dict | None:
    for row in rows:
        cell = row.get(column) if column else next(iter(row.values()))
        if cell is not None and re.search(rf"`{re.escape(key)}`", cell):
            return row
    return None


def _shows_default(cell: str, default) -> bool:
    if isinstance(default, bool):
        return str(default).lower() in cell.lower()
    if isinstance(default, (int, float)):
        return any(float(t) == default for t in re.findall(r"-?\d+(?:\.\d+)?", cell.replace(",", "")))
    if isinstance(default, str):
        return default in cell
    if isinstance(default, dict):
        return "{}" in cell if not default else all(str(k) in cell for k in default)
    return ("[]" in cell) if not default else all(_shows_default(cell, d) for d in default)


def _check_table(rows: list[dict], props: dict, where: str, column: str | None = None) -> int:
    """Every key of ``props`` has a row; where the schema gives a default and the table a default
    column, the row shows it. Returns how many keys were checked."""
    for key, sub in props.items():
        row = _row(rows, key, column)
        assert row is not None, f"{where}: no row for `{key}`"
        if "default" in sub and "default" in row:
            assert _shows_default(row["default"], sub["default"]), f"{where}: `{key}` default {sub['default']!r}"
    return len(props)


def test_reference_pages_list_every_schema_key_with_its_default():
    checked = 0
    # maps: the top level, the shapes, the base keys of every format
    s = schema("map")
    rows = _rows(_sections("map-yaml")["nhstab YAML"])
    checked += _check_table(rows, s["properties"], "map-yaml")
    checked += _check_table(rows, {k: {} for sub in s["$defs"]["shape"]["oneOf"] for k in sub["properties"]},
                            "map-yaml shapes")
    for name, sub in s["$defs"].items():
        if name.startswith("base_"):
            checked += _check_table(rows, {k: v for k, v in sub["properties"].items()}, f"map-yaml {name}")
    # robots: the keys, the stabilizer's, each model's parameters and defaults
    s = schema("robot")["$defs"]
    rows = _rows(_sections("robot-yaml")["Keys"])
    checked += _check_table(rows, s["robot"]["properties"], "robot-yaml")
    checked += _check_table(rows, s["stabilizer"]["properties"], "robot-yaml stabilizer")
    model = None
    by_model: dict[str, list] = {}
    for row in rows:
        if "parameter" in row:
            model = re.sub(r"`", "", row["model"]) or model
            by_model.setdefault(model, []).append(row)
    for cond in s["robot"]["allOf"]:
        name = cond["if"]["properties"]["model"]["const"]
        params = {k: v for k, v in cond["then"]["properties"].items() if k not in ROBOT_KEYS}
        checked += _check_table(by_model[name], params, f"robot-yaml {name}", "parameter")
    # run configs: the top level and every section (the tube's on its own page)
    s = schema("run-config")["properties"]
    sections = _sections("run-config")
    checked += _check_table(_rows(sections["Top-level keys"]), s, "run-config")
    for name, sub in s.items():
        if sub.get("type") == "object":
            text = (REFERENCE / "tube-options.md").read_text() if name == "tube" else sections[name]
            checked += _check_table(_rows(text), sub["properties"], f"run-config {name}")
    # batch configs: the top level, a map entry, the grid
    s = schema("batch-config")["properties"]
    rows = _rows(_sections("batch-config")["Keys"])
    checked += _check_table(rows, s, "batch-config")
    checked += _check_table(rows, s["maps"]["items"]["properties"], "batch-config maps")
    checked += _check_table(rows, s["grid"]["properties"], "batch-config grid")
    assert checked >= 120


@pytest.mark.parametrize("args,kind", [(["run", "--config", "example:warehouse_replan", "--print-config"], "run-config"),
                                       (["batch", "example:depot_robustness", "--print-config"], "batch-config")])
def test_printed_effective_configs_satisfy_their_schemas(args, kind):
    """What ``--print-config`` prints (every option with its default filled in) is a config of its format."""
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    data = yaml.safe_load(res.output)
    assert isinstance(data, dict) and "controller" in (data if kind == "run-config" else data["run"])
    assert _errors(kind, data) == []
