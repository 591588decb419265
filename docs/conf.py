"""Sphinx configuration of tissuebench's documentation (``pip install -e ".[docs]"``, then
``sphinx-build -W --keep-going -b html docs out/docs``; ``tox -e docs``; ``.ci/run`` builds it).

Pages are MyST Markdown. The tutorials are MyST notebooks (``{code-cell}``) that myst-nb runs at
every build, each in a fresh temporary folder: their outputs and figures come from that run, and a
cell that fails fails the build. The reference pages are generated from the code by the local
extension ``_ext/tbdocs.py``. ``-D nb_execution_mode=off`` skips the tutorials' runs for a quick
look at the prose (never in CI).
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent / "_ext"))

import tissuebench  # noqa: E402

project = "tissuebench"
author = "the tissuebench developers"
copyright = "the tissuebench developers, MIT licence"
release = version = tissuebench.__version__

extensions = ["myst_nb", "sphinx.ext.autodoc", "numpydoc", "sphinx.ext.mathjax", "tbdocs"]
exclude_patterns = ["_build", "studies/*.md", "bring_your_own_organ", "**/.ipynb_checkpoints"]
source_suffix = {".md": "myst-nb", ".rst": "restructuredtext"}
root_doc = "index"

# MyST: $...$ maths, ::: fences, definition lists; heading anchors for [](#...) links
myst_enable_extensions = ["colon_fence", "dollarmath", "deflist"]
myst_heading_anchors = 3

# myst-nb: every tutorial runs at every build, in a temporary folder, and an error fails the build
nb_execution_mode = "force"
nb_execution_in_temp = True
nb_execution_timeout = 600
nb_execution_raise_on_error = True
nb_execution_show_tb = True
nb_merge_streams = True

# autodoc + numpydoc: the API reference from the docstrings
autodoc_default_options = {"members": True, "member-order": "bysource"}
autodoc_typehints = "none"
numpydoc_show_class_members = False
numpydoc_validation_checks = set()

html_theme = "alabaster"
html_title = "tissuebench"
html_static_path = []
# the package's docstrings cite modules with :mod: and attributes it does not document here
nitpicky = False
suppress_warnings = ["myst.header"]
