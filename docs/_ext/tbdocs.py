"""Sphinx extension of tissuebench's documentation: the reference pages generated from the code.

At ``builder-inited`` (before any page is read) it writes ``docs/_generated/*.md`` from the code
(:mod:`tbdocs_formats`, :mod:`tbdocs_pages`): the command line, the scene and spec formats, the
results store, the methods and the catalogue with its pictures. Nothing generated is checked in
(``.gitignore``), so a page cannot drift from the code it documents.

It also prepares the tutorials' execution (myst-nb runs each in a temporary folder): the
kernel inherits this process's environment, so the interpreter's folder goes first on ``PATH``
(``%%bash`` cells run ``tissuebench`` of the environment building the docs), this folder is on
``PYTHONPATH`` (a hidden first cell runs :func:`tbdocs_kernel.setup`), and pictures are rendered
off screen.
"""
from __future__ import annotations

import importlib
import inspect
import os
import sys
import time
from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import Directive


def _generate(app) -> None:
    from tbdocs_pages import write_all

    start = time.perf_counter()
    write_all(Path(app.srcdir) / "_generated")
    print(f"tbdocs: reference pages generated from the code in {time.perf_counter() - start:.1f} s")


class Docstring(Directive):
    """``{docstring} module.name``: the module's docstring as a preformatted block, for docstrings
    written as plain text (aligned tables) that reST would misread; the words stay in the code."""

    required_arguments = 1

    def run(self):
        module = importlib.import_module(self.arguments[0])
        text = inspect.getdoc(module) or ""
        return [nodes.literal_block(text, text, language="text")]


def setup(app):
    os.environ["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])
    # the kernel imports tbdocs_kernel (a hidden first cell: the strict %%bash, the example files)
    here = str(Path(__file__).resolve().parent)
    os.environ["PYTHONPATH"] = os.pathsep.join([here] + [p for p in [os.environ.get("PYTHONPATH")] if p])
    os.environ.setdefault("MPLBACKEND", "Agg")
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    app.connect("builder-inited", _generate)
    app.add_directive("docstring", Docstring)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
