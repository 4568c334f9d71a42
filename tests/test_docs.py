"""The documentation site (docs/) builds without a warning, and every relative link of the docs and
the README points at a file of the repository."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: the docs extra of pyproject.toml, by import name
DOCS_MODULES = ("sphinx", "myst_parser", "sphinx_click", "furo")


def _missing_docs_modules() -> list[str]:
    return [name for name in DOCS_MODULES if importlib.util.find_spec(name) is None]


@pytest.mark.slow
def test_the_docs_build_without_a_warning(tmp_path):
    """`sphinx-build -W --keep-going -b html docs OUT`, as docs/development.md says: -W makes every
    warning (a broken cross-reference, a docstring autodoc cannot parse, a page outside the toctree)
    an error."""
    missing = _missing_docs_modules()
    if missing:
        pytest.skip("the docs extra is not installed (pip install -e '.[docs]'): no " + ", ".join(missing))
    out = tmp_path / "html"
    res = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                          "-d", str(tmp_path / "doctrees"), str(DOCS), str(out)],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-4000:]
    assert "WARNING" not in res.stderr and "ERROR" not in res.stderr, res.stderr[-4000:]
    for page in ("index", "reference/limits", "reference/api", "reference/commands", "theory/control-law"):
        assert (out / f"{page}.html").is_file(), page
    # the API reference documents the public names, the command reference every command
    api = (out / "reference" / "api.html").read_text()
    assert "nhstab.execute" in api and "nhstab.load_map" in api
    commands = (out / "reference" / "commands.html").read_text()
    assert all(f'id="nhstab-{c}"' in commands for c in ("run", "plan", "batch", "map", "parking", "tubes", "bench"))


_LINK = re.compile(r"\]\(([^)\s]+)\)")


@pytest.mark.parametrize("page", sorted([*DOCS.rglob("*.md"), ROOT / "README.md"]),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_into_the_repository(page):
    """Every relative link resolves to a file or folder of this repository (the pages also read on
    GitHub), and no page points outside it."""
    text = page.read_text()
    bad = []
    for target in _LINK.findall(text):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        path = (page.parent / target.split("#")[0]).resolve()
        if not path.exists() or ROOT not in path.parents:
            bad.append(target)
    assert not bad, bad
    assert "shared/" not in text and "NOTES.md" not in text


def _keys_documented(page: str, keys) -> list[str]:
    text = (DOCS / "reference" / page).read_text()
    return [k for k in keys if f"`{k}`" not in text]


def test_the_format_references_name_every_key_the_loaders_accept():
    """Every key a loader accepts has its row in the reference page of its format."""
    from dataclasses import fields

    from nhstab.batch import config as batch_config
    from nhstab.execution import config as run_config
    from nhstab.execution.controllers import ControllerOptions
    from nhstab.maps import ros, yaml_format
    from nhstab.models import MODELS, make_model
    from nhstab.robot import ROBOT_KEYS, STABILIZER_KEYS

    missing = _keys_documented("map-yaml.md", [*yaml_format._TOP_KEYS, *{k for keys in yaml_format._BASE_KEYS.values()
                                                                       for k in keys}, *ros.ALLOWED_KEYS])
    params = {p for name in MODELS for p in make_model(name).params()}
    missing += _keys_documented("robot-yaml.md", [*ROBOT_KEYS, *STABILIZER_KEYS, *params, *MODELS])
    sections = {name: [f.name for f in fields(cls)] for name, cls in run_config._SECTIONS.items()}
    sections["controller"] = [f.name for f in fields(ControllerOptions)]
    sections["sensor"] = ["range_m", "fov_deg", "rate_hz", "resolution_deg", "mount"]   # degrees in files
    sections["noise"] = ["scale", "initial", "sensor", "process", "impulses", "distribution", "per"]
    missing += _keys_documented("run-config.md", [*run_config._TOP, *(k for name, keys in sections.items()
                                                                      if name != "tube" for k in keys)])
    missing += _keys_documented("tube-options.md", sections["tube"])
    missing += _keys_documented("batch-config.md", [*batch_config._TOP, *batch_config._MAP_KEYS,
                                                    *batch_config._GRID_KEYS])
    assert not missing, missing
