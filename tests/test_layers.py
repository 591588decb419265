"""The layer rule of docs/explanation/architecture.md ("each layer imports only the ones above it"), checked on every
import of the package, those inside functions included (issue 29: 41 cross-package imports hid
inside functions, among them ``studies`` drawing with ``reports``); and imports of another
package inside a function say why (a ``# lazy:`` comment), except in ``cli.py``, whose
docstring states its one reason."""
from __future__ import annotations

import ast
from pathlib import Path

import tissuebench

#: the layout table of docs/explanation/architecture.md, top to bottom: a package may import itself and those before it
LAYERS = ("refsolvers", "cases", "reference", "rom", "studies", "reports", "testing")
ROOT = Path(tissuebench.__file__).parent


def _node_imports(node, package):
    """The tissuebench packages one import statement of a module at ``package`` (its path
    parts below ``ROOT``) names."""
    if isinstance(node, ast.ImportFrom):
        if node.level:  # relative: resolve against the module's package
            base = list(package[:-1])[: len(package) - node.level] if node.level > 1 else list(package[:-1])
            parts = base + (node.module.split(".") if node.module else [])
            return [parts[0]] if parts else [alias.name for alias in node.names]
        if node.module and node.module.split(".")[0] == "tissuebench":
            return node.module.split(".")[1:2] or [a.name for a in node.names]
        return []
    if isinstance(node, ast.Import):
        return [a.name.split(".")[1] for a in node.names if a.name.startswith("tissuebench.")]
    return []


def _imports(path: Path):
    """``(line, imported tissuebench package)`` of every import in ``path``."""
    package = path.relative_to(ROOT).parts
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        yield from ((node.lineno, n) for n in _node_imports(node, package))


def _function_imports(path: Path):
    """``(line, package, has_reason)`` of every import of another tissuebench layer inside a
    function of ``path``; the reason is a ``# lazy:`` comment on the import or the 3 lines above."""
    package = path.relative_to(ROOT).parts
    source = path.read_text(encoding="utf-8")
    lines = source.splitlines()
    for fn in ast.walk(ast.parse(source)):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                for name in _node_imports(node, package):
                    if name in LAYERS and name != package[0]:
                        around = lines[max(0, node.lineno - 4):node.lineno]
                        yield node.lineno, name, any("# lazy:" in text for text in around)


def test_no_layer_imports_a_layer_below_it():
    broken = []
    for path in sorted(ROOT.rglob("*.py")):
        layer = path.relative_to(ROOT).parts[0]
        if layer not in LAYERS:
            continue  # cli.py, __init__.py: the top, they may import anything
        allowed = set(LAYERS[: LAYERS.index(layer) + 1])
        broken += [f"{path.relative_to(ROOT)}:{line} imports {name}" for line, name in _imports(path)
                   if name in LAYERS and name not in allowed]
    assert not broken, "\n".join(broken)


def test_the_checker_sees_an_import_inside_a_function(tmp_path, monkeypatch):
    """The test above can fail: a ``reports`` import inside a ``studies`` function is found."""
    fake = tmp_path / "studies" / "x.py"
    fake.parent.mkdir()
    fake.write_text("def f():\n    from ..reports import html\n    from tissuebench.reports.gate import check\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path)
    assert [n for _, n in _imports(fake)] == ["reports", "reports"]


def test_imports_of_another_package_inside_a_function_say_why():
    """Imports belong at the module top; one inside a function hides a dependency (the layer
    rule was broken behind 41 of them), so each states its reason. ``cli.py`` imports the
    package's subcommand modules in its handlers, so a command loads only what it runs."""
    assert "imported inside the handlers" in (ROOT / "cli.py").read_text(encoding="utf-8")
    silent = [f"{path.relative_to(ROOT)}:{line} imports {name}" for path in sorted(ROOT.rglob("*.py"))
              if path.name != "cli.py" or path.parent != ROOT
              for line, name, why in _function_imports(path) if not why]
    assert not silent, "\n".join(silent)


def test_the_reason_checker_can_fail(tmp_path, monkeypatch):
    fake = tmp_path / "rom" / "x.py"
    fake.parent.mkdir()
    fake.write_text("def f():\n    from ..cases import load\n\n\ndef g():\n"
                    "    # lazy: gmsh is an optional extra\n    from ..cases import builders\n"
                    "    from .base import Training\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path)
    assert list(_function_imports(fake)) == [(2, "cases", False), (7, "cases", True)]
