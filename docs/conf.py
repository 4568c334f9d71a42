"""Sphinx configuration of the nhstab documentation (MyST Markdown pages, autodoc with numpy-style
docstrings through napoleon, the command reference from the click commands)."""

from __future__ import annotations

import re

from nhstab import __version__

project = "nhstab"
author = "the nhstab authors"
copyright = "the nhstab authors, BSD-3-Clause"
release = __version__
version = __version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx_click",
]

source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]

# MyST: $...$ maths, definition lists, ::: fences; headings get anchors for #links
myst_enable_extensions = ["dollarmath", "deflist", "colon_fence"]
myst_heading_anchors = 3

# autodoc: the public names of `nhstab`, in source order, with their type hints in the signature
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
napoleon_numpy_docstring = True
napoleon_google_docstring = False

html_theme = "furo"
html_title = f"nhstab {version}"

# Pages link the committed results and map notes by their relative paths (../../results/...), which
# GitHub follows. For the site, a link to a Markdown file outside docs/ becomes a download link
# (MyST's path: scheme), since it is not a page of the site.
_OUTSIDE_MD = re.compile(r"\]\(((?:\.\./)+(?:results|maps|tests|pipeline)/[^)#\s]+\.md)\)")


def _link_outside_markdown(app, docname, source):
    source[0] = _OUTSIDE_MD.sub(r"](path:\1)", source[0])


def setup(app):
    app.connect("source-read", _link_outside_markdown)
