"""Sphinx configuration of hevr's documentation site.

Build (offline: no intersphinx, nothing fetched)::

    .venv/bin/pip install -e '.[docs]'
    .venv/bin/python -m sphinx -W --keep-going -b html docs docs/_build/html

The pages are Markdown (MyST); the API reference is generated from the numpydoc docstrings
(autodoc + numpydoc), the CLI reference from ``hevr.cli.parser.build_parser()``, the protocol's
endpoint reference from the OpenAPI document of ``hevr serve`` and the benchmark plots from the
committed results in ``benchmarks/``, all at build time by the extensions in ``docs/_ext/``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")

import hevr  # noqa: E402

project = "hevr"
author = "hevr's authors"
copyright = "hevr's authors"  # noqa: A001
release = version = hevr.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "numpydoc",
    "hevr_api",
    "hevr_cli",
    "hevr_openapi",
    "hevr_bench",
]

# no smart quotes: "--force" in a help text or a page stays two hyphens, not an en dash
smartquotes = False

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_generated", "images/README*", "Thumbs.db", ".DS_Store"]
templates_path: list[str] = []

# MyST: heading anchors so that the pages' ``file.md#section`` links resolve, ``:::`` fences,
# definition lists and field lists (no ``$`` maths: the pages write shell variables such as $HEVR_KNOWN_STORES).
myst_enable_extensions = ["colon_fence", "deflist", "fieldlist"]
myst_heading_anchors = 4

# autodoc / numpydoc: the docstrings are numpydoc; the lazily re-exported names of ``hevr`` are
# documented as ``hevr.NAME``.
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "none"  # signatures without annotations: numpydoc's Parameters sections give the types
autodoc_preserve_defaults = False  # True fails on some multi-line signatures (Plane.oblique)
autosummary_generate = False
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_validation_checks: set[str] = set()

# no network at build time
intersphinx_mapping: dict = {}

html_theme = "pydata_sphinx_theme"
html_title = f"hevr {release}"
html_static_path: list[str] = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "header_links_before_dropdown": 5,
    "secondary_sidebar_items": ["page-toc"],
}
html_copy_source = False
html_show_sourcelink = False
# a page without sub-pages has no section navigation to show: no left sidebar there
html_sidebars = {
    page: []
    for page in (
        "index",
        "getting-started",
        "security",
        "format",
        "image-format",
        "sums-format",
        "inputs",
        "api-contract",
        "benchmarks",
        "reference/api",
        "reference/cli",
    )
}
