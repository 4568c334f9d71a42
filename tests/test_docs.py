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
