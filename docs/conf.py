"""Sphinx configuration of the mtwip-twin documentation.

Build (warnings are errors, as CI builds it)::

    pip install '.[docs]'
    python -m sphinx -W --keep-going -b html docs docs/_build/html

Pages are Markdown (MyST); the reference pages are generated from the code at build time
(``docs/_ext/twin_reference.py``: the CLI from its click commands, the scenario keys from
``twin.scenarios.schema.describe()``, the metrics from ``twin.outputs.metrics``) and the Python
API from the docstrings (autodoc with numpydoc). Results and benchmark tables are written into
``docs/_generated/`` by the scripts in ``benchmarks/`` that measure them.
"""
from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))  # the checkout's twin, also when it is not installed

project = "mtwip-twin"
author = "the mtwip-twin authors"
copyright = "2026, the mtwip-twin authors"
release = version = "0.1.0"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "numpydoc",
    "twin_reference",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}  # .rst: numpydoc's autosummary
root_doc = "index"
# investigations/: working notes kept beside the images, not pages of the site; _build: the output
exclude_patterns = ["_build", "investigations", "reference/_auto", "_generated", "**/.pytest_cache"]

myst_enable_extensions = ["colon_fence", "deflist", "dollarmath"]
myst_heading_anchors = 4  # [text](page.md#a-heading) links resolve, and are checked

# autodoc and numpydoc: the code's docstrings are numpydoc-style prose
autodoc_member_order = "bysource"
autodoc_inherit_docstrings = False  # a base class's docstring (gymnasium.Env.step) is not ours
autodoc_typehints = "none"          # signatures show them; numpydoc's sections carry the rest
autodoc_preserve_defaults = True    # a default as written (DEFAULT_RATES), not its nested repr (RunSpec's 20 lines)
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set = set()
numpydoc_xref_param_type = False

nitpicky = False
# commands in prose stay as typed: smart quotes would turn 'twin run --log-sensors' into curly
# quotes and an en dash, and a copied command would fail
smartquotes = False
suppress_warnings: list[str] = []

html_theme = "furo"
html_title = "mtwip-twin"
html_static_path: list[str] = []

# numpydoc also parses the raw docstrings for signatures and warns (Python warnings, not Sphinx's)
# about the sections it does not know; twin_reference turns those into rubrics for the page
import warnings  # noqa: E402

warnings.filterwarnings("ignore", category=UserWarning, module="numpydoc.docscrape")
